"""neubrdf: NeuBRDF (Dou, Zheng et al. 2024) Tables 3 and 4 on our data, and sparse-measurement pruning, all through
`neumat fit-many` on the CPU path: Table 3 (image losses against NBRDF; GGX on RGL) on the RGL files and on the 25
MERL-like tables of the shared NBRDF networks (the paper's MERL), Table 4 (the grid without quantisation, with 4-bit
features, with the codebook) on the MERL-like tables, the RGL files again with replayed measurements and a pruned
grid. NeuBRDF runs at the default preset (recommended) and as the paper's exact model (preset cpu). Shared codebooks
(Sec. 3.3) through `neumat fit-clusters` on the MERL-like tables, each member beside its own fit."""
from __future__ import annotations

import json
from pathlib import Path

from neumat.cli.fit_job import source_sha256
from neumat.io.shared_data import shared_data_dir

from .. import harness
from .common import cli, fit_many, fits_figure, method_key, paper_budget, quality_rows, recipe_budget, summary_rows

NAME = "neubrdf"
DESCRIPTION = ("NeuBRDF's Table 3 (RGL and MERL-like, against NBRDF and GGX), Table 4 (quantisation), pruning and "
               "shared codebooks, through neumat fit-many")
TABLE3_MODELS = ["neubrdf", "nbrdf", "ggx"]
MERL_MODELS = ["neubrdf", "nbrdf"]
#: fit-many's evaluation options of a full run (the eval protocol's image metrics at 64 spp, 128^2)
FULL_EVAL = ["--n-configs", str(2 ** 18), "--image-spp", "64", "--image-resolution", "128"]
#: the paper's exact model on the CPU path, beside the default
PAPER_MODEL = ["--preset", "cpu"]
#: Table 4's grids besides the codebook (PAPER_MODEL's rows), on the CPU path of the paper's model: "w/o
#: quantization" its dense grid to the end; "w low-bit" 4-bit features, trained in one phase (a 4-bit grid has no
#: coarse start to be regridded from)
QUANTISATION = {"neubrdf-dense": PAPER_MODEL + ["--set", "dense_warmup=0", "--set", "vq_candidates=0"],
                "neubrdf-lowbit4": PAPER_MODEL + ["--set", "features=lowbit", "--set", "lowbit_bits=4", "--set",
                                                  "coarse_fraction=0", "--set", "dense_warmup=0", "--set",
                                                  "vq_candidates=0"]}
#: the RGL files' own measurements replayed, pruned to (PRUNING) and not (REPLAY), by the paper's model on the CPU path
#: less its coarse start (a pruned grid cannot be regridded), drawn balanced over direction cells ("replay_cells");
#: and the same on uniform draws of the measurements (PRUNING_UNIFORM, REPLAY_UNIFORM): neither draw is the better
#: on every file (docs/neubrdf.md, "Sparse measurements and pruning")
REPLAY = PAPER_MODEL + ["--set", "coarse_fraction=0", "--set", "queries=replay_cells"]
PRUNING = REPLAY + ["--set", "prune=true"]
REPLAY_UNIFORM = PAPER_MODEL + ["--set", "coarse_fraction=0", "--set", "queries=replay"]
PRUNING_UNIFORM = REPLAY_UNIFORM + ["--set", "prune=true"]
QUICK = ["--preset", "cpu", "--steps", "30", "--set", "neubrdf:nside=4", "--set", "neubrdf:index_bits=4",
         "--set", "batch_size=1024", "--n-configs", "4096", "--image-spp", "4", "--image-resolution", "32"]
#: fit-clusters of a full run: the clusters of the shared-codebook study (k 6 over the 25 MERL-like tables), at the
#: default preset and Table 4's evaluation queries
CLUSTERS = ["-k", "6", "--n-configs", str(2 ** 18)]
QUICK_CLUSTERS = ["-k", "1", "--preset", "cpu", "--steps", "30", "--set", "nside=4", "--set", "index_bits=4", "--set",
                  "batch_size=1024", "--set", "cluster_steps=20", "--set", "cluster_resolution=8", "--n-configs",
                  "4096"]
#: its fits are independent jobs: --workers / --shard share them out
SHARDS = True
BUDGET = {
    "quick": {"ours": "neubrdf (N_side 4, b 4) and nbrdf, 30 steps x 1024 on analytic GGX and paper_white, one seed; "
                      "images 32^2 at 4 spp; the two in one shared-neubrdf cluster",
              "paper": paper_budget(MERL_MODELS) + " on a GPU",
              "expected_wall": "about 15 s"},
    "full": {"ours": f"CPU recipes: {recipe_budget(TABLE3_MODELS)}; Table 3: 5 RGL files x 3 models and 25 MERL-like "
                     "tables x 2 models, each with neubrdf also as the paper's model (preset cpu); Table 4: the 25 "
                     "MERL-like tables x the paper's model's dense and 4-bit grids; seeds 0 and 1; pruning: 5 RGL "
                     "files x the paper's model (preset cpu, no coarse start) on their replayed measurements, pruned "
                     "and not, drawn balanced over cells and uniformly, seed 0 (310 fits); images 128^2 at 64 "
                     "spp; shared codebooks: fit-clusters -k 6 of the 25 MERL-like tables at the default preset, "
                     "seed 0",
             "paper": paper_budget(MERL_MODELS) + " on a GPU; MERL's 100 measured tables (we have 25 NBRDF "
                      "stand-ins) and RGL's 51",
             "expected_wall": "about 15 h one job after another at one thread, 7-8 h with --workers 2 "
                              "(CPU seconds, medians, sessions 76-79: on RGL the ggx, nbrdf, neubrdf and "
                              "neubrdf-paper fits 30, 72, 145 and 180 s, on the MERL-like tables the nbrdf, neubrdf "
                              "and neubrdf-paper jobs 78, 181 and 200 s, Table 4's dense and 4-bit grids 150 and "
                              "214 s, the fit-clusters job 73 min, a pruning job 170 s; the results page sums them "
                              "all)"},
}


def run(run: harness.Run) -> None:
    """Fit, evaluate and tabulate; a quick run fits tiny models for seconds."""
    from neumat.render.comparison import PROTOCOL

    run.protocol["image"] = PROTOCOL
    data = shared_data_dir()
    seeds = [run.seed] if run.quick else [run.seed, run.seed + 1]
    if data is None:
        run.skip("RGL and MERL-like sources", "shared data absent (neumat.io.shared_data)")
        rgl, merl = [], []
    else:
        rgl = [str(p) for p in sorted((data / "rgl").glob("*_rgb.bsdf"))]
        merl = [str(p) for p in sorted((data / "merl" / "nbrdf_fits").glob("*.h5"))]
    if run.quick:
        sources = ["ggx:roughness=0.2", *rgl[-1:]]
        rows = fit_many(run, sources, MERL_MODELS, QUICK, seeds)
        run.table("table3", "Quick: tiny fits (numbers mean nothing; the suite runs)", quality_rows(rows),
                  figure=fits_figure(run, rows, sources[0], MERL_MODELS, QUICK))
        run.table("summary", "Quick: per-model means", summary_rows(rows))
        run.table("sharing", "Quick: the sources in one shared-neubrdf cluster",
                  _sharing_rows(_clusters(run, sources, QUICK_CLUSTERS, run.seed), rows, run.seed))
        run.skip("the MERL-like tables (Tables 3 and 4) and pruning", "--quick")
        return
    _full(run, rgl, merl, seeds)


def _neubrdf_as(run: harness.Run, name: str, options: list[str], sources: list[str], seeds: list[int]) -> list[dict]:
    """Rows of NeuBRDF fits with `options` (and the full evaluation), named `name` in the tables."""
    rows = fit_many(run, sources, ["neubrdf"], options + FULL_EVAL, seeds)
    return [{**r, "model": name} for r in rows]


def _full(run: harness.Run, rgl: list[str], merl: list[str], seeds: list[int]) -> None:
    """The full run's tables."""
    if not rgl:
        return
    # the longest job (about 1.5 h at one thread) first: with --workers / --shard the fits run beside it, not after
    shared = _clusters(run, merl, CLUSTERS, seeds[0]) if merl else None
    rows3 = fit_many(run, rgl, TABLE3_MODELS, FULL_EVAL, seeds)
    figure3 = fits_figure(run, rows3, rgl[0], TABLE3_MODELS, FULL_EVAL)
    rows3 += _neubrdf_as(run, "neubrdf-paper", PAPER_MODEL, rgl, seeds)
    run.table("table3", "Table 3 on the RGL files (default presets; neubrdf-paper: the paper's model)",
              quality_rows(rows3), figure=figure3)
    run.table("table3_summary", "Table 3 on the RGL files per model: mean over the files, seed spread",
              summary_rows(rows3))
    merl_rows = fit_many(run, merl, MERL_MODELS, FULL_EVAL, seeds)
    figure_merl = fits_figure(run, merl_rows, merl[0], MERL_MODELS, FULL_EVAL) if merl else None
    codebook = _neubrdf_as(run, "neubrdf-paper", PAPER_MODEL, merl, seeds)
    run.table("table3_merl", "Table 3 on the MERL-like tables (the paper's data is MERL; default presets; "
                             "neubrdf-paper: the paper's model)", quality_rows(merl_rows + codebook),
              figure=figure_merl)
    run.table("table3_merl_summary", "Table 3 on the MERL-like tables per model: mean over the tables, seed spread",
              summary_rows(merl_rows + codebook))
    pruned = _neubrdf_as(run, "neubrdf-pruned", PRUNING, rgl, seeds[:1])
    pruned += _neubrdf_as(run, "neubrdf-unpruned", REPLAY, rgl, seeds[:1])
    pruned += _neubrdf_as(run, "neubrdf-pruned-uniform", PRUNING_UNIFORM, rgl, seeds[:1])
    pruned += _neubrdf_as(run, "neubrdf-unpruned-uniform", REPLAY_UNIFORM, rgl, seeds[:1])
    run.table("pruning", "Pruning: the paper's model (preset cpu, no coarse start) on the RGL files' replayed "
                         "measurements, its grid pruned to them and not, the measurements drawn balanced over "
                         "direction cells and (-uniform) uniformly", quality_rows(pruned))
    grids = [row for name, options in QUANTISATION.items() for row in _neubrdf_as(run, name, options, merl, seeds)]
    run.table("table4", "Table 4 on the MERL-like tables: the paper's model without quantisation (dense), with 4-bit "
                        "features (lowbit4) and with its codebook (paper); bytes include the MLP (2 x 64, 12,935 "
                        "bytes), which the paper's memory column leaves out", quality_rows(grids + codebook))
    run.table("table4_summary", "Table 4 per grid: mean over the tables, seed spread (the paper's MSE is over MERL's "
                                "cells; rmse_hdr over cosine-weighted directions)",
              summary_rows(grids + codebook, ("log_err", "rmse_hdr", "img_mae", "img_ssim", "img_flip")))
    run.table("sharing", "Shared codebooks (Sec. 3.3): fit-clusters -k 6 of the MERL-like tables, each member "
                         "beside its own NeuBRDF fit at the default preset (same seed, same queries)",
              _sharing_rows(shared, merl_rows, seeds[0]))


def _clusters(run: harness.Run, sources: list[str], options: list[str], seed: int) -> dict | None:
    """The clusters.json of a `neumat fit-clusters` run, one job of the run (from its ledger or a --work folder
    when either holds it); None in a shard that leaves it to another."""
    def clusters() -> dict:
        with run.folder("fit-clusters", sources, options, seed) as out:
            if not (out / "clusters.json").exists():
                cli(["fit-clusters", *sources, *options, "--seed", str(seed), "--threads", str(run.threads), "-q",
                     "-o", str(out)])
            return json.loads((out / "clusters.json").read_text())

    key = {"job": "fit-clusters", "sources": {Path(s).name: source_sha256(s) for s in sources}, "options": options,
           "seed": seed, **method_key("neubrdf", options)}
    return run.job(f"fit-clusters of {len(sources)} sources (seed {seed})", key, clusters, keep=lambda _: True)


def _sharing_rows(doc: dict | None, own: list[dict], seed: int) -> list[dict]:
    """One row per source of a fit-clusters document `doc` (`_clusters`; none for None): its cluster, bytes (its
    index grid and a share of the cluster's codebook and MLP) and reflectance errors, beside its own NeuBRDF
    fit's in `own` (fit-many rows of model "neubrdf" at `seed`, the default preset in a full run)."""
    if doc is None:
        return []
    alone = {r["name"]: r for r in own if r["model"] == "neubrdf" and r["seed"] == seed and r["status"] == "ok"}
    size = {c["cluster"]: len(c["members"]) for c in doc["clusters"]}
    rows = []
    for m in doc["materials"].values():
        a = alone.get(m["name"], {})
        rows.append({"source": m["name"], "cluster": m["cluster"], "cluster size": size[m["cluster"]],
                     "log_err": m["metrics"]["log_err"], "rmse_hdr": m["metrics"]["rmse_hdr"],
                     "bytes": m["bytes_fp16"], "own log_err": a.get("metrics", {}).get("log_err"),
                     "own rmse_hdr": a.get("metrics", {}).get("rmse_hdr"), "own bytes": a.get("bytes_fp16")})
    return rows
