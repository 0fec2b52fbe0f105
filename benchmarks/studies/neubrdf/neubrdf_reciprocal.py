"""Replayed RGL measurements with and without their reciprocal pairs (recipe option measured_reciprocal).

Question: a replayed fit of an RGL file overshoots at grazing outgoing angles, where the file's nodes are few;
does training each measured (wi, wo) also as (wo, wi) lower its error? One fit per (file, variant), the paper's
model (`--preset paper`) on `replay` queries, unpruned; log error and HDR errors over 2^16 cosine-weighted
configurations against the file's interpolant (what `neumat eval --against` reports). Appends a JSON line per fit.

    python -m benchmarks.studies.neubrdf.neubrdf_reciprocal cc_ibiza_sunset --seed 0 --out reciprocal.jsonl
"""
from __future__ import annotations

import argparse
import json
import time

import torch

from neumat.catalog.open_material import open_material
from neumat.fit.preset import build_fit
from neumat.fit.trainer import fit
from neumat.metrics.hdr import reflectance_errors


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("files", nargs="+", help="RGL file names under --data, without _rgb.bsdf")
    ap.add_argument("--data", default="../shared/data/rgl")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--steps", type=int, default=2500)
    ap.add_argument("--batch-size", type=int, default=4096)
    ap.add_argument("--out", default="reciprocal.jsonl")
    args = ap.parse_args()
    torch.set_num_threads(1)
    for name in args.files:
        rgl = open_material(f"{args.data}/{name}_rgb.bsdf")
        for reciprocal in (False, True):
            model, r = build_fit("neubrdf", "paper", source=rgl, seed=args.seed, overrides={
                "steps": args.steps, "batch_size": args.batch_size, "lr_decay_every": args.steps // 4,
                "queries": "replay", "measured_reciprocal": reciprocal})
            cpu = time.process_time()
            res = fit(model, rgl, r.recipe, progress=False)
            row = dict(name=name, reciprocal=reciprocal, seed=args.seed, steps=args.steps,
                       cpu_seconds=time.process_time() - cpu, warnings=res.warnings,
                       **reflectance_errors(res.model, rgl, n=2 ** 16, seed=1))
            print(json.dumps(row), flush=True)
            with open(args.out, "a") as f:
                f.write(json.dumps(row) + "\n")


if __name__ == "__main__":
    main()
