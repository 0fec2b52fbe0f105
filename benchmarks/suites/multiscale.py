"""multiscale: the multi-scale gated SVBRDF (Timonen et al. 2025) against its FLOP-matched baselines on the shared
texture sets, through `neumat fit-many` at the CPU recipes (Tables 4 and 6 on our data)."""
from __future__ import annotations

from .. import harness
from .common import paper_budget, quality_rows, recipe_budget, summary_rows, texture_set_fits

NAME = "multiscale"
DESCRIPTION = "the multi-scale gated SVBRDF against neumip, tripleplane, nbrdf-uv and ggx-mipmap, through fit-many"
MODELS = ["multiscale", "neumip", "tripleplane", "nbrdf-uv", "ggx-mipmap"]
BUDGET = {
    "quick": {"ours": "multiscale and ggx-mipmap, 10 steps x 256 on Wood092_1K at 32^2 texels, one seed",
              "paper": paper_budget(MODELS) + " on a GPU", "expected_wall": "about 20 s"},
    "full": {"ours": f"CPU recipes: {recipe_budget(MODELS)}; 6 texture sets at 256^2 texels x 5 models, seeds 0 and "
                     "1 (60 fits); sphere images 128^2 at 64 spp",
             "paper": paper_budget(MODELS) + " on a GPU, at the sets' full resolution",
             "expected_wall": "about 11 h one fit after another (one thread)"},
}


def run(run: harness.Run) -> None:
    """Fit and tabulate; the scale series (paper Fig. 4 / Table 6) is `neumat eval --scales 9` on the fitted files."""
    from neumat.render.comparison import PROTOCOL

    run.protocol["image"] = PROTOCOL
    rows = texture_set_fits(run, MODELS, ["multiscale", "ggx-mipmap"])
    if rows is None:
        return
    run.table("fits", "Texture sets x models (sphere images: the texture at about one scale)", quality_rows(rows))
    run.table("summary", "Per model: mean over the sets, seed spread", summary_rows(rows))
    run.skip("the scale series (Fig. 4, Table 6's FLIP over scales)", "not in fit-many: `neumat eval MODEL.nmat "
             "--against SET --scales 9` per fitted file")
