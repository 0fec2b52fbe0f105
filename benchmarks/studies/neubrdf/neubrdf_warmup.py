"""NeuBRDF at equal CPU wall time: end-to-end VQ (the paper) vs a dense warm-up then VQ (recipe option
dense_warmup) vs dense features only (Table 4's "w/o quantization"), on RGL materials at N_side 16 and 32.

Each arm fits by replaying 2^18 cosine-weighted measurements of the material (batch 8192, lr 1e-2 halved
four times over the run, EMA 0.01, one torch thread); its step count is the wall budget divided by the
seconds per step measured for that arm (dense and VQ steps timed on steps 10 - 40 of a fit, the warm-up
arm's as the mix; the "fit s" column shows how equal the times came out on a loaded machine). Reported: held-out log_cos error (`reflectance_errors` log_err, 2^18 fresh cosine queries against the
measured material) and the stored size (fp16 floats).

    PYTHONPATH=src python benchmarks/studies/neubrdf/neubrdf_warmup.py [--seconds 60] [--warmup 0.5] [--out FILE]
    PYTHONPATH=src python benchmarks/studies/neubrdf/neubrdf_warmup.py --materials /work/merl_tables/gold-paint.binary   # any file

--materials: RGL names (in ../shared/data/rgl) or material files (a MERL-like table from `neumat data convert
NAME.h5 NAME.binary`, an .nmat, ...); --nsides the grid sizes; --steps N[,M...] gives every arm the same step
counts instead of the same wall time (a budget series: does the codebook close on the dense grid with training?);
--index-bits b: the codebook's size 2^b (paper: 9), for a capacity series.
"""
from __future__ import annotations

import argparse
import platform
import subprocess
from dataclasses import replace
from pathlib import Path

import torch

from neumat.catalog.open_material import open_material
from neumat.fit.measured_samples import MeasuredSamples
from neumat.fit.method import recipe_for
from neumat.fit.trainer import fit
from neumat.metrics.hdr import cosine_queries, reflectance_errors
from neumat.methods.neubrdf.model import NeuBRDF

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "rgl"
MATERIALS = ("vch_golden_yellow_rgb", "cc_iris_purple_gem_rgb")


def run(source, nside: int, features: str, warmup: float, steps: int, log_every: int = 0, index_bits: int = 9):
    """(fitted model, FitResult) of `steps` steps of arm (features, warmup); index_bits b (2^b codewords)."""
    r = recipe_for("neubrdf")
    recipe = replace(r, steps=steps, batch_size=8192, lr_decay_every=max(steps // 4, 1),
                     log_every=log_every or max(steps, 1), queries="replay",
                     options={**r.options, "dense_warmup": warmup})
    torch.manual_seed(0)
    model = NeuBRDF(nside=nside, features=features, index_bits=index_bits)
    res = fit(model, source, recipe, progress=False, device="cpu")
    return res.model, res


def seconds_per_step(source, nside: int, features: str) -> float:
    """Wall seconds per training step, from steps 10 to 40 of a fit (start-up and first steps excluded)."""
    h = run(source, nside, features, 0.0, 40, log_every=10)[1].history
    return (h[-1]["seconds"] - h[0]["seconds"]) / 30


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--seconds", type=float, default=60.0, help="wall seconds of training per arm")
    p.add_argument("--warmup", type=float, default=0.5, help="dense_warmup fraction of the warm-up arm")
    p.add_argument("--out", default="benchmarks/studies/neubrdf/results/neubrdf_warmup.md")
    p.add_argument("--materials", nargs="+", default=list(MATERIALS), help="RGL names or material files")
    p.add_argument("--nsides", nargs="+", type=int, default=[16, 32])
    p.add_argument("--steps", default=None, help="N[,M...]: equal steps per arm instead of --seconds")
    p.add_argument("--index-bits", type=int, default=9, help="codebook size 2^b of the VQ arms (paper: 9)")
    a = p.parse_args()
    torch.set_num_threads(1)
    rows = []
    for spec in a.materials:
        path = Path(spec) if Path(spec).is_file() else DATA / f"{spec}.bsdf"
        name = path.stem
        ref = open_material(str(path))
        pool = cosine_queries(2 ** 18, torch.Generator().manual_seed(1), torch.device("cpu"))
        source = MeasuredSamples.from_material(ref, pool, name=name)
        for nside in a.nsides:
            budgets = [int(n) for n in a.steps.split(",")] if a.steps else [None]
            per_step = {} if a.steps else {f: seconds_per_step(source, nside, f) for f in ("dense", "vq")}
            for budget in budgets:
                arms = [("end-to-end VQ", "vq", 0.0), (f"dense warm-up {a.warmup:g} then VQ", "dense", a.warmup),
                        ("dense only", "dense", 0.0)]
                for label, features, warmup in arms:
                    if budget is None:
                        sps = (per_step["dense"] * warmup + per_step["vq"] * (1 - warmup) if label != "dense only"
                               else per_step["dense"])
                        steps = max(int(a.seconds / sps), 2)
                    else:
                        steps = budget
                    model, res = run(source, nside, features, warmup, steps, index_bits=a.index_bits)
                    err = reflectance_errors(model, ref, n=2 ** 18, seed=7)["log_err"]
                    rows.append((name, nside, label, steps, res.seconds, err, model.size_bytes(), budget))
                    print(*rows[-1], flush=True)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    budget = f"--steps {a.steps}" if a.steps else f"--seconds {a.seconds:g}"
    lines = [f"# NeuBRDF: dense warm-up vs end-to-end VQ vs dense, equal {'steps' if a.steps else 'CPU wall time'}",
             "",
             f"Command: `PYTHONPATH=src python benchmarks/studies/neubrdf/neubrdf_warmup.py {budget} "
             f"--warmup {a.warmup:g} --index-bits {a.index_bits} --materials {' '.join(a.materials)} --nsides {' '.join(map(str, a.nsides))}`; "
             f"commit {commit}; {platform.machine()} {platform.processor() or ''}, "
             "one torch thread on a shared, loaded 2-core machine (wall times are noisy).", "",
             "Replay of 2^18 cosine-weighted measurements, batch 8192, lr 1e-2 halved every steps/4, EMA 0.01, "
             f"k 16, b {a.index_bits}, MLP 2 x 64. log_err: held-out cosine-weighted log error (2^18 fresh queries, "
             "`neumat.metrics.hdr.reflectance_errors`); bytes: `NeuBRDF.size_bytes()` (fp16).", "",
             "| material | N_side | arm | steps | fit s | log_err | bytes | log_err / dense |",
             "|---|---|---|---|---|---|---|---|"]
    dense = {(r[0], r[1], r[7]): r[5] for r in rows if r[2] == "dense only"}
    for name, nside, label, steps, seconds, err, size, budget in rows:
        lines.append(f"| {name} | {nside} | {label} | {steps} | {seconds:.0f} | {err:.4f} | {size:,} | "
                     f"{err / dense[(name, nside, budget)]:.2f} |")
    Path(a.out).write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
