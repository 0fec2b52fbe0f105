"""multiscale: the multi-scale gated SVBRDF (Timonen et al. 2025) against its FLOP-matched baselines on the shared
texture sets, through `neumat fit-many` at the default presets (Tables 4 and 6 on our data)."""
from __future__ import annotations

from .. import harness
from .common import default_budget, paper_budget, quality_rows, summary_rows, texture_set_fits

NAME = "multiscale"
DESCRIPTION = "the multi-scale gated SVBRDF against neumip, tripleplane, nbrdf-uv and ggx-mipmap, through fit-many"
MODELS = ["multiscale", "neumip", "tripleplane", "nbrdf-uv", "ggx-mipmap"]
#: its fits are independent jobs: --workers / --shard share them out
SHARDS = True
BUDGET = {
    "quick": {"ours": "multiscale and ggx-mipmap, 10 steps x 256 on Wood092_1K at 32^2 texels with 8-sample "
                       "footprint targets, one seed; scale series of 3 scales at 16^2 pixels",
              "paper": paper_budget(MODELS) + " on a GPU", "expected_wall": "about 10 s"},
    "full": {"ours": f"default presets on a CPU: {default_budget(MODELS)}; "
                     "the 6 texture sets whole (1K: the texel density the paper fits and `neumat fit SET` reads; "
                     "downsampled, their normal detail flattens) x 5 models, seeds 0 and 1 (60 fits); sphere "
                     "images 128^2 at 64 spp; the scale series (9 scales x 4 lights x 3 tilts, 48^2 pixels) of "
                     "every fit",
             "paper": paper_budget(MODELS) + " on a GPU, at the sets' full resolution",
             "expected_wall": "about 12 h one job after another, about half with --workers 2 (measured on the "
                              "2-core Xeon, sessions 70-75, two shards side by side: the 60 jobs' own times sum to "
                              "12.0 h, a job (fit, images, scale series) 3-25 min, median 7-9 for the 4000-step "
                              "models and 15 for neumip at 8000; plus each set's references, made once: a few "
                              "minutes a set)"},
}


def run(run: harness.Run) -> None:
    """Fit, score each fit's scale series (paper Fig. 4 / Table 6: FLIP of the plane scene from 1/8 texel to 2
    textures per pixel, as `neumat eval --scales`) and tabulate."""
    from neumat.render.comparison import PROTOCOL

    run.protocol["image"] = PROTOCOL
    n_scales, resolution = (3, 16) if run.quick else (9, 48)
    run.protocol["scale_series"] = f"{n_scales} scales x 4 lights x 3 tilts, plane scene at {resolution}^2 pixels"

    def scale_series(row: dict) -> dict:
        from neumat.catalog.modelfile import load_model
        from neumat.catalog.open_material import open_material
        from neumat.render.scale_series import score_scale_series

        reader = dict(max_size=32, samples=8) if run.quick else {}  # as the fits read the set
        series = score_scale_series(load_model(row["nmat"]), open_material(row["source"], **reader),
                                    n_scales=n_scales, resolution=resolution)
        return {"scales": series}

    fits = texture_set_fits(run, MODELS, ["multiscale", "ggx-mipmap"], after=scale_series, max_size=None)
    if fits is None:
        return
    rows, figure = fits
    run.table("fits", "Texture sets x models (sphere images: the texture at about one scale)", quality_rows(rows),
              figure=figure)
    run.table("summary", "Per model: mean over the sets, seed spread", summary_rows(rows))
    series = [{**r, "metrics": {"scale_flip": r["scales"]["flip_mean"]}} for r in rows if r["status"] == "ok"]
    run.table("scales_summary", "Scale series per model (the paper's Table 6 metric): each fit's mean FLIP over the "
                                "scales, mean over the sets, seed spread", summary_rows(series, ("scale_flip",)))
    run.table("scales", "Scale series: FLIP per scale (scale 0 the finest; floor: the reference against itself)",
              [{"source": r["name"], "model": r["model"], "seed": r["seed"],
                "texels per pixel": " ".join(f"{t:.3g}" for t in r["scales"]["texels_per_pixel"]),
                "FLIP": " ".join(f"{f:.4f}" for f in r["scales"]["flip"]),
                "mean": r["scales"]["flip_mean"], "floor mean": r["scales"]["floor_mean"]}
               for r in rows if r["status"] == "ok"])
