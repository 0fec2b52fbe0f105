"""Where do the latent-texture models overpredict by orders of magnitude? (session 76)

The multiscale suite's whole-set fits of the gated model have rmse_hdr 0.04-5.0 where the other models have
0.005-0.14, at log errors like theirs. This script scores every fitted model of a ledger (and any `--model
NMAT SOURCE [CROP]` given) on the reflectance metric's queries (the first 2^16 cosine-weighted queries of
`neumat.metrics.hdr.reflectance_errors` at seed 0, per query seed) and reports how often and how far a model's
value exceeds the reference's: the ratio (sum of RGB + FLOOR) / (reference's + FLOOR), FLOOR = 0.3 (0.1 a channel,
so a model a little above a reference near zero is not counted), its share above 3 and 10, its maximum with that
query's angles, and rmse_hdr. With `--bound-batches N` (session 77), each gated or tripleplane model is
scored again with the output bound its fit now records (`multiscale.Config.output_bound`): the largest target per
channel over N batches of its training distribution (the recipe's footprint queries, 2^12 a batch, 32-sample
targets), once per source; the default recipe's fit sees 4000 batches, its own bound the largest of those.

    python -m benchmarks.studies.multiscale.grazing_outliers --ledger benchmarks/results/multiscale/full.jsonl \
        --model /tmp/wood64.nmat ../shared/data/svbrdf/Wood092_1K 64 --out benchmarks/studies/multiscale/results/grazing_outliers.md
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import torch

from benchmarks.harness import code
from neumat.catalog.modelfile import load_model
from neumat.cli.fitting import open_training_source
from neumat.fit.footprint_queries import FootprintOptions, with_target_samples
from neumat.fit.query_samplers import QUERY_SAMPLERS
from neumat.methods.latent_mlp.multiscale import MultiScale
from neumat.metrics.hdr import cosine_queries

FLOOR = 0.3
QUERIES = 2 ** 16


def scores(model, reference, seed: int) -> dict:
    """The over-prediction statistics of `model` against `reference` on one seed's queries."""
    q = cosine_queries(QUERIES, torch.Generator().manual_seed(seed), "cpu", True)
    with torch.no_grad():
        f, g = reference.eval(q).double(), model.eval(q).double()
    ratio = (g.sum(1) + FLOOR) / (f.sum(1) + FLOOR)
    i = int(ratio.argmax())
    return {"over3": float((ratio > 3).double().mean()), "over10": float((ratio > 10).double().mean()),
            "max": float(ratio[i]), "ref": float(f[i].mean()), "value": float(g[i].mean()),
            "wi_z": float(q.wi[i, 2]), "wo_z": float(q.wo[i, 2]),
            "cos_io": float((q.wi[i] * q.wo[i]).sum()), "rmse_hdr": float((g - f).square().mean().sqrt())}


def training_bound(model, source, batches: int, seed: int = 5) -> torch.Tensor:
    """The largest target per channel over `batches` batches of the CPU recipe's training distribution."""
    options = FootprintOptions()
    targets = with_target_samples(source, 32)
    draw = QUERY_SAMPLERS.get("footprint")(targets, model, fine_bias=options.fine_bias,
                                           elongation_std=options.elongation_std)
    g, top = torch.Generator().manual_seed(seed), torch.zeros(3)
    with torch.no_grad():
        for _ in range(batches):
            top = torch.maximum(top, targets.eval(draw(4096, g, "cpu"))[:, :3].amax(0).float())
    return top


def _each(per_seed: list[dict], key: str, fmt: str) -> str:
    """One statistic of every query seed, comma-separated."""
    return ", ".join(format(x[key], fmt) for x in per_seed)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ledger", type=Path, help="a benchmark ledger (JSON lines) whose fits to score (those whose "
                                                    "model file is still in the --work folder it names)")
    parser.add_argument("--model", nargs="+", action="append", default=[], metavar="NMAT SOURCE [CROP]",
                        help="also a model file, its texture set and the crop it was fitted on")
    parser.add_argument("--seeds", type=int, default=2, help="query seeds (default 2)")
    parser.add_argument("--bound-batches", type=int, default=0,
                        help="also score the gated and tripleplane models with the output bound of this many "
                             "training batches (module docstring)")
    parser.add_argument("--out", type=Path, help="write the Markdown table here")
    args = parser.parse_args()
    torch.set_num_threads(1)
    jobs = []
    if args.ledger:
        for line in args.ledger.read_text().splitlines():
            entry = json.loads(line)
            row = entry["result"]
            if isinstance(row, dict) and row.get("status") == "ok" and row.get("nmat") and Path(row["nmat"]).is_file():
                jobs.append((entry["what"], row["nmat"], row["source"], None))
    for spec in args.model:
        nmat, source, *crop = spec
        jobs.append((f"{Path(source).name} (crop {crop[0]}) x {Path(nmat).name}" if crop else Path(nmat).name,
                     nmat, source, int(crop[0]) if crop else None))
    references, bounds, lines = {}, {}, []
    bounded = args.bound_batches > 0
    header = ("| fit | share > 3x | share > 10x | largest ratio (reference, model, wi_z, wo_z, wi.wo) | rmse_hdr |"
              + (" bound | largest ratio, rmse_hdr bounded |" if bounded else "") + "\n|---|---|---|---|---|"
              + ("---|---|" if bounded else ""))
    print(header)
    for what, nmat, source, crop in jobs:
        key = (source, crop)
        if key not in references:
            references[key] = open_training_source("multiscale", [source], {} if crop is None else {"crop": crop})
        model = load_model(nmat).runtime()
        s = [scores(model, references[key], seed) for seed in range(args.seeds)]
        worst = max(s, key=lambda x: x["max"])
        line = (f"| {what} | {_each(s, 'over3', '.1e')} | {_each(s, 'over10', '.1e')} | "
                f"{worst['max']:.1f} ({worst['ref']:.2f}, {worst['value']:.2f}, {worst['wi_z']:.3f}, "
                f"{worst['wo_z']:.3f}, {worst['cos_io']:.2f}) | {_each(s, 'rmse_hdr', '.3f')} |")
        if bounded:
            if isinstance(model, MultiScale) and model.cfg.output_bound:
                if model.output_bound_values() is None:  # a fit from before the bound: its source's, once
                    if key not in bounds:
                        bounds[key] = training_bound(model, references[key], args.bound_batches)
                    model.target_max.copy_(bounds[key])
                b = [scores(model, references[key], seed) for seed in range(args.seeds)]
                line += (f" {model.target_max.mean():.2f} | {max(x['max'] for x in b):.1f}, "
                         f"{_each(b, 'rmse_hdr', '.3f')} |")
            else:
                line += " - | - |"
        print(line, flush=True)
        lines.append(line)
    if args.out:
        now = code()
        said = (f"Commit {now['commit'][:7]}{' (modified)' if now['dirty'] else ''}; query seeds 0-{args.seeds - 1}, "
                f"{QUERIES} queries each, FLOOR {FLOOR}" + (f"; bounds from {args.bound_batches} batches" if bounded
                                                            else "") + ".")
        args.out.write_text("\n".join([header, *lines, "", said, ""]))

if __name__ == "__main__":
    main()
