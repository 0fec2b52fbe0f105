"""The paper's default NeuBRDF (N_side 64, k 16, b 9, MLP 2 x 64) at equal wall time per training path
(issue 32, tasks 2 and 4: Table 4's codebook / dense ratio at the paper's sizes, the fastest path to the
codebook model's quality on a CPU).

Arms (`--arms`, each fitted through the one trainer on the source itself, online queries): "vq" (the paper's
end-to-end straight-through VQ over all 2^b codewords), "dense" (dense per-slot features, "w/o quantization",
1.6 MB at fp16: Table 4's comparator), "lowbit" (Table 4's 4-bit features, 0.4 MB), or recipe options as
KEY=VALUE[,KEY=VALUE...] of a VQ model trained through a dense warm-up: warmup=F (dense_warmup), candidates=K
(vq_candidates), coarse=C (coarse_fraction, at N_side 16), runtime=R (runtime_fraction: the last R of the steps
in the 1/4-weight form against pixel-pair averages), e.g. "coarse=0.4,warmup=0.7,candidates=8"; a spec with
coarse but no warmup is a dense model.

Equal time: each arm's step count is `--seconds` divided by its seconds per step, measured on this source
before the fits through the same trainer (coarse, dense, VQ and restricted-VQ steps timed separately, the mean of
12 steps after 12; runtime steps are counted at the cost of the phase before them, so arms with one run longer than
--seconds: see "fit s"). Batch 8192,
lr 1e-2 halved at 1/2 and 3/4 of each phase (schedule "halves"), EMA 0.01, the loss log_cos. Every fitted
model is scored in its shipped form (`runtime()`: 1/4 corner weights, fp16): held-out reflectance errors (2^18
cosine queries, seed 7), Table 4's metric (the MSE over the MERL table's cells, `merl_table_mse`) and image
metrics under the comparison protocol (`neumat.render.comparison`) beside the reference's noise floor. The
arms "vq", "lowbit" and "dense" are Table 4's three rows; "grid bytes" is Table 4's memory (fp16, the low-bit
grid at its 4 bits, no MLP).

    OMP_NUM_THREADS=1 PYTHONPATH=src python benchmarks/studies/neubrdf/neubrdf_paper_size.py --materials FILE... \
        [--seconds 300] [--arms vq warmup=0.7 warmup=0.7,candidates=8 dense] [--queries cosine] [--out FILE]

A results section (command, commit, machine, table) is appended to `--out`.
"""
from __future__ import annotations

import argparse
import platform
import subprocess
import sys
import time
import warnings
from dataclasses import replace
from pathlib import Path

import torch

from neumat.catalog.open_material import open_material
from neumat.fit.method import recipe_for
from neumat.fit.trainer import FitWarning, fit
from neumat.metrics.hdr import reflectance_errors
from neumat.methods.neubrdf.model import NeuBRDF
from neumat.reflectance.tabulate import merl_table_mse, tabulate_merl
from neumat.render.comparison import image_comparison, reference_renders

BATCH = 8192


OPTION_NAMES = {"warmup": "dense_warmup", "candidates": "vq_candidates", "coarse": "coarse_fraction",
                "runtime": "runtime_fraction"}


def parse_arm(spec: str) -> tuple[str, dict]:
    """(features the model is built with, recipe options) of an arm spec (module docstring)."""
    if spec in ("vq", "dense", "lowbit"):
        return spec, {}
    options = {}
    for item in spec.split(","):
        key, _, value = item.partition("=")
        if key not in OPTION_NAMES or not value:
            raise SystemExit(f"unknown arm {spec!r}: expected vq, dense or KEY=VALUE,... with KEY in "
                             f"{', '.join(OPTION_NAMES)}")
        options[OPTION_NAMES[key]] = int(value) if key == "candidates" else float(value)
    return "dense", options


def step_seconds(model: NeuBRDF, source, queries: str, steps: int = 12) -> float:
    """Mean wall seconds of a training step of `model` through the library trainer (`neumat.fit.trainer.fit`: one
    online phase of the paper recipe, the model's own optimiser, EMA, batch BATCH, targets from `source`): the
    last `steps` of a fit of 2 x `steps` steps, between its two history records (the trainer's rollback snapshot is
    taken before the first of them, so neither it nor the warm-up steps are in the time)."""
    recipe = replace(recipe_for("neubrdf"), steps=2 * steps, batch_size=BATCH, queries=queries, log_every=steps,
                     checkpoint_every=2 * steps)
    with warnings.catch_warnings():  # a few timed steps, not a fit to judge
        warnings.simplefilter("ignore", FitWarning)
        history = fit(model, source, recipe, progress=False, device="cpu").history
    return (history[-1]["seconds"] - history[0]["seconds"]) / steps


def per_step_costs(source, queries: str, arms: list[str]) -> dict:
    """Seconds per step of each phase kind the arms run: "coarse" (dense at N_side 16), "dense" and "vq" (all
    codewords) at N_side 64, and ("vq", K) for K candidates."""
    torch.manual_seed(0)
    costs = {"coarse": step_seconds(NeuBRDF(nside=16, features="dense"), source, queries),
             "dense": step_seconds(NeuBRDF(features="dense"), source, queries),
             ("vq", 0): step_seconds(NeuBRDF(features="vq"), source, queries)}
    if "lowbit" in arms:
        costs["lowbit"] = step_seconds(NeuBRDF(features="lowbit"), source, queries)
    for spec in arms:
        k = parse_arm(spec)[1].get("vq_candidates", 0)
        if ("vq", k) not in costs:
            model = NeuBRDF(features="dense").quantize_from_dense(iterations=2, candidates=k)
            costs[("vq", k)] = step_seconds(model, source, queries)
    return costs


def arm_step_seconds(spec: str, costs: dict) -> float:
    """Mean seconds per step of an arm from the phase costs."""
    features, options = parse_arm(spec)
    if not options:
        return costs[features] if features != "vq" else costs[("vq", 0)]
    coarse, warmup = options.get("coarse_fraction", 0.0), options.get("dense_warmup", 0.0)
    dense_end = warmup if warmup else 1.0
    vq = costs[("vq", options.get("vq_candidates", 0))]
    return coarse * costs["coarse"] + (dense_end - coarse) * costs["dense"] + (1 - dense_end) * vq


def fit_arm(source, spec: str, steps: int, queries: str, seed: int):
    features, options = parse_arm(spec)
    r = recipe_for("neubrdf")
    recipe = replace(r, steps=steps, batch_size=BATCH, schedule="halves", log_every=max(steps, 1),
                     checkpoint_every=max(steps, 1), queries=queries, seed=seed, options={**r.options, **options})
    torch.manual_seed(seed)
    return fit(NeuBRDF(features=features), source, recipe, progress=False, device="cpu")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--materials", nargs="+", required=True, help="material files (MERL .binary, RGL .bsdf, ...)")
    ap.add_argument("--seconds", type=float, default=300.0, help="wall seconds of training per arm")
    ap.add_argument("--arms", nargs="+", default=["vq", "warmup=0.7", "warmup=0.7,candidates=8",
                                                      "coarse=0.4,warmup=0.7,candidates=8", "dense"])
    ap.add_argument("--queries", default="cosine", help="training query sampler (cosine, rusinkiewicz)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--spp", type=int, default=256)
    ap.add_argument("--resolution", type=int, default=96)
    ap.add_argument("--out", default="benchmarks/studies/neubrdf/results/neubrdf_paper_size.md")
    a = ap.parse_args()
    torch.set_num_threads(1)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    header = ("| material | arm | steps | fit s | log_err | rel_err | image MAE | SSIM | FLIP | floor MAE | floor SSIM "
              "| grid bytes | log_err / dense | table MSE | MSE / dense |")
    rows = []
    print(header, flush=True)
    for path in a.materials:
        source = open_material(path)
        name = Path(path).stem
        costs = per_step_costs(source, a.queries, a.arms)
        renders = reference_renders(source, a.spp, a.resolution)
        table = tabulate_merl(source)
        dense_err = dense_mse = None
        results = []
        for spec in a.arms:
            steps = max(int(a.seconds / arm_step_seconds(spec, costs)), 4)
            res = fit_arm(source, spec, steps, a.queries, a.seed)
            model = res.model.runtime()
            err = reflectance_errors(model, source, n=2 ** 18, seed=7)
            img = image_comparison(model, source, a.spp, a.resolution, renders=renders)
            mse = merl_table_mse(model, table)
            results.append((spec, steps, res.seconds, err, img, model.grid_size_bytes(), mse))
            if spec == "dense":
                dense_err, dense_mse = err["log_err"], mse
        for spec, steps, seconds, err, img, size, mse in results:
            ratio = f"{err['log_err'] / dense_err:.2f}" if dense_err else ""
            mse_ratio = f"{mse / dense_mse:.2f}" if dense_mse else ""
            rows.append(f"| {name} | {spec} | {steps} | {seconds:.0f} | {err['log_err']:.5f} | {err['rel_err']:.3f} | "
                        f"{img['mae']:.4f} | {img['ssim']:.4f} | {img['flip']:.4f} | {img['floor_mae']:.5f} | "
                        f"{img['floor_ssim']:.4f} | {size:,} | {ratio} | {mse:.4g} | {mse_ratio} |")
            print(rows[-1], flush=True)
        cost_text = ", ".join(f"{k if isinstance(k, str) else f'VQ {k[1] or 2 ** 9} candidates'} {v:.3f} s"
                              for k, v in costs.items())
        rows.append(f"|  | seconds per step of {BATCH} on {name}: {cost_text} |" + " |" * 13)
    section = [f"## {time.strftime('%Y-%m-%d')}: {a.seconds:g} s per arm, queries {a.queries}, seed {a.seed}", "",
               f"Command: `OMP_NUM_THREADS=1 PYTHONPATH=src python {' '.join(sys.argv)}`; commit {commit}; "
               f"{platform.machine()}, one torch thread on a 2-core machine (other jobs running: wall times are "
               f"approximate). Images: {a.resolution}^2, {a.spp} spp, comparison protocol; models scored in "
               "their shipped form.", "", header, "|" + "---|" * 15, *rows, ""]
    out = Path(a.out)
    if not out.exists():
        out.write_text("# NeuBRDF at the paper's sizes: training paths at equal wall time (issue 32)\n\n"
                       "Written by `benchmarks/studies/neubrdf/neubrdf_paper_size.py` (its docstring says what each arm is).\n\n")
    with out.open("a") as f:
        f.write("\n".join(section) + "\n")
    print("\n".join(section))


if __name__ == "__main__":
    main()
