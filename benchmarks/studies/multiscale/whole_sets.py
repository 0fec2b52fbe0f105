"""Session 75: which latent-texture model does a whole 1K texture set want at the CPU default? Each (set, model) is
fitted by `neumat fit SET --model MODEL --seed S` (the recommended preset, the set read whole, as a user runs it)
and scored by the multiscale suite's scale series (9 scales x 4 lights x 3 tilts at 48^2: `neumat eval --scales
9 --resolution 48`); one JSON line per fit appended to OUT/rows.jsonl. The shared sets' rows come from the
multiscale suite's full run (benchmarks/results/multiscale/full.jsonl); this script held the procedural sets out
(`neumat data texture-set KIND --size 1024 --seed 0 -o DIR`). Results: results/whole_sets.md.

    python -m benchmarks.studies.multiscale.whole_sets OUT SET... --models neumip,multiscale,tripleplane --seed 0
"""
from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from pathlib import Path


def fit_and_score(source: str, model: str, seed: int, out: Path) -> dict:
    """Fit `model` to `source` (kept as OUT/<set>.<model>.s<seed>.nmat: a second run scores it again) and score
    its scale series."""
    import torch

    from neumat.catalog.modelfile import load_model
    from neumat.catalog.open_material import open_material
    from neumat.render.scale_series import score_scale_series

    name = Path(source).name
    nmat = out / f"{name}.{model}.s{seed}.nmat"
    start, cpu = time.time(), resource.getrusage(resource.RUSAGE_CHILDREN).ru_utime
    if not nmat.exists():
        done = subprocess.run([sys.executable, "-m", "neumat", "fit", source, "--model", model, "--seed", str(seed),
                               "--threads", "1", "-o", str(nmat)], capture_output=True, text=True)
        (out / f"{name}.{model}.s{seed}.log").write_text(done.stdout + done.stderr)
        if done.returncode:
            said = done.stderr.strip().splitlines() or ["no message"]
            raise SystemExit(f"{name} x {model}: the fit failed: {said[-1]}")
    fit_wall, fit_cpu = time.time() - start, resource.getrusage(resource.RUSAGE_CHILDREN).ru_utime - cpu
    torch.set_num_threads(1)
    series = score_scale_series(load_model(str(nmat)), open_material(source), n_scales=9, resolution=48)
    return {"name": name, "model": model, "seed": seed, "flip_mean": series["flip_mean"], "flip": series["flip"],
            "floor_mean": series["floor_mean"], "fit_wall_s": fit_wall, "fit_cpu_s": fit_cpu}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", type=Path, help="folder of the fits and rows.jsonl")
    parser.add_argument("sets", nargs="+", help="texture-set folders")
    parser.add_argument("--models", default="neumip,multiscale,tripleplane", help="comma-separated models")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    for source in args.sets:
        for model in args.models.split(","):
            row = fit_and_score(source, model, args.seed, args.out)
            with open(args.out / "rows.jsonl", "a") as f:
                f.write(json.dumps(row) + "\n")
            print(json.dumps(row))


if __name__ == "__main__":
    main()
