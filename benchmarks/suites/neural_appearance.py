"""neural-appearance: Real-Time Neural Appearance Models (Zeltner et al. 2024) against the neumip-frame and
ggx-mipmap baselines on the shared texture sets, through `neumat fit-many` at the CPU recipes (its image table)."""
from __future__ import annotations

from .. import harness
from .common import paper_budget, quality_rows, recipe_budget, summary_rows, texture_set_fits

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
    rows = texture_set_fits(run, MODELS, MODELS[:1])
    if rows is None:
        return
    run.table("fits", "Texture sets x models", quality_rows(rows))
    run.table("summary", "Per model: mean over the sets, seed spread", summary_rows(rows))
    run.skip("sampler variance (Sec. 6.3)", "not yet a suite table: benchmarks/studies/neural_appearance/"
             "neural_appearance_sampler.py holds the last measurement")
