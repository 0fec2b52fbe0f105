"""neural-appearance: Real-Time Neural Appearance Models (Zeltner et al. 2024) against the neumip-frame and
ggx-mipmap baselines on the shared texture sets, through `neumat fit-many` at the CPU recipes (its image table)."""
from __future__ import annotations

from neumat.io.shared_data import shared_data_dir

from .. import harness
from .common import fit_many, paper_budget, quality_rows, recipe_budget, summary_rows

NAME = "neural-appearance"
DESCRIPTION = "neural-appearance against neumip-frame and ggx-mipmap on the texture sets, through fit-many"
MODELS = ["neural-appearance", "neumip-frame", "ggx-mipmap"]
BUDGET = {
    "quick": {"ours": "neural-appearance, 10 steps x 256 on Wood092_1K at 32^2 texels, one seed",
              "paper": paper_budget(MODELS[:1]) + " on a GPU", "expected_wall": "about 15 s"},
    "full": {"ours": f"CPU recipes: {recipe_budget(MODELS)}; 6 texture sets at 256^2 texels x 3 models, seeds 0 "
                     "and 1 (36 fits); sphere images 128^2 at 64 spp",
             "paper": paper_budget(MODELS[:1]) + " on a GPU (the paper's own layered materials, not available)",
             "expected_wall": "about 5 h one fit after another (one thread)"},
}


def run(run: harness.Run) -> None:
    """Fit and tabulate."""
    from neumat.render.comparison import PROTOCOL

    run.protocol["image"] = PROTOCOL
    data = shared_data_dir()
    if data is None:
        run.skip("every fit", "no texture sets: shared data absent (neumat.io.shared_data)")
        return
    sets = sorted(str(p) for p in (data / "svbrdf").iterdir() if p.is_dir())
    if run.quick:
        rows = fit_many(run, sets[-1:], MODELS[:1],
                        ["--preset", "cpu", "--steps", "10", "--set", "batch_size=256", "--source-option",
                         "max_size=32", "--n-configs", "4096", "--image-spp", "2", "--image-resolution", "32"], [run.seed])
    else:
        rows = fit_many(run, sets, MODELS, ["--preset", "cpu", "--source-option", "max_size=256", "--n-configs",
                                            str(2 ** 18), "--image-spp", "64", "--image-resolution", "128"],
                        [run.seed, run.seed + 1])
    run.table("fits", "Texture sets x models", quality_rows(rows))
    run.table("summary", "Per model: mean over the sets, seed spread", summary_rows(rows))
    run.skip("sampler variance (Sec. 6.3)", "not yet a suite table: benchmarks/studies/neural_appearance/"
             "neural_appearance_sampler.py holds the last measurement")
