"""Controlled comparisons on the selection-free protocol's rows (`selection_free.py`): one recipe variant against
another per model, split into the tuning pairs (each set's first crop, seed 0) and the held-out ones (its other
crops, seed 1), the texture-set default (`neumat.methods.latent_mlp.regime`) against the better of the gated
model and tripleplane per (crop, seed), and every model's FLIP over tripleplane's (issue 55's 1.5x criterion),
at the default steps or at a step budget beside tripleplane's at the default and at the same budget.

Usage: python -m benchmarks.studies.multiscale.selection_free_compare CROPS.json JOBS.jsonl [JOBS.jsonl ...]
       [--against BASE:VARIANT ...] [--regime VARIANT ...] [--ratio VARIANT[@STEPS] ...]
(a variant is a row's `variant` label, "" for the recipe as it ran; several JOBS files are read as one)."""
from __future__ import annotations

import argparse
import json
import statistics

from neumat.methods.latent_mlp.regime import DIELECTRIC_METALNESS, FLAT_TILT_DEG

MODELS = ("multiscale", "tripleplane", "neumip", "neumip-frame", "neumip-offset", "nbrdf-uv", "ggx-mipmap")


def _index(crops: list[dict], rows: list[dict], steps: int | None = None) -> tuple[dict, dict]:
    """{(set, origin, model, seed, variant): row} of the finished fits at `steps` (None: the recipe's), {set: first
    crop origin}."""
    first: dict = {}
    for c in crops:
        first.setdefault(c["name"], tuple(c["origin"]))
    by = {(r["name"], tuple(r["origin"]), r["model"], r["seed"], r.get("variant") or ""): r
          for r in rows if r["status"] == "ok" and (r.get("steps") or None) == steps}
    return by, first


def _flip(r: dict) -> float:
    return r["scales"]["flip_mean"]


def against(crops: list[dict], rows: list[dict], base: str, variant: str) -> str:
    """Per model: on how many (crop, seed) pairs `variant` has the lower mean FLIP than `base`, the median and range
    of variant / base, and the worst fit's final / lowest loss under `variant`."""
    by, first = _index(crops, rows)
    lines = [f"| model | pairs | lower with {variant or 'the base'} | median ratio | range | worst final/lowest |",
             "|---|---|---|---|---|---|"]
    every = []
    for model in MODELS:
        for part, held in (("tuning", False), ("held out", True)):
            pairs = [(k, r) for k, r in by.items() if k[2] == model and k[4] == variant
                     and (k[0], k[1], model, k[3], base) in by and (k[3] != 0 or first[k[0]] != k[1]) == held]
            if not pairs:
                continue
            ratios = [_flip(r) / _flip(by[(k[0], k[1], model, k[3], base)]) for k, r in pairs]
            worst = max(r["final_loss"] / r["best_loss"] for _, r in pairs)
            every += ratios
            lines.append(f"| {model} ({part}) | {len(ratios)} | {sum(x < 1 for x in ratios)} | "
                         f"{statistics.median(ratios):.3f} | {min(ratios):.2f}-{max(ratios):.2f} | {worst:.2f} |")
    if every:
        lines += ["", f"All models: lower on {sum(x < 1 for x in every)} of {len(every)} pairs, median ratio "
                      f"{statistics.median(every):.3f}"]
    return "\n".join(lines)


def regime(crops: list[dict], rows: list[dict], variant: str) -> str:
    """Per (crop, seed): the gated / tripleplane mean FLIP ratio under `variant`, the crop's mean normal tilt and
    metalness, the model the texture-set rule picks and whether it is the better one; then the rule's regret (its
    pick's FLIP over the better one's) against always fitting the gated model."""
    by, first = _index(crops, rows)
    stats = {(c["name"], tuple(c["origin"])): c["stats"] for c in crops}
    lines = ["| crop | seed | pair | tilt deg | metalness | gated / tripleplane | rule picks | the better |",
             "|---|---|---|---|---|---|---|---|"]
    right = total = 0
    regret, regret_gated = [], []
    for k, g in sorted(by.items(), key=lambda kv: (kv[0][0], kv[0][1], kv[0][3])):
        t = by.get((k[0], k[1], "tripleplane", k[3], variant))
        if k[2] != "multiscale" or k[4] != variant or t is None:
            continue
        s = stats[(k[0], k[1])]
        flat = s["tilt_deg"] < FLAT_TILT_DEG and s["metalness_mean"] < DIELECTRIC_METALNESS
        ratio = _flip(g) / _flip(t)
        good = (ratio >= 1) == flat
        right += good
        total += 1
        best = min(_flip(g), _flip(t))
        regret.append((_flip(t) if flat else _flip(g)) / best)
        regret_gated.append(_flip(g) / best)
        held = "held out" if (k[3] != 0 or first[k[0]] != k[1]) else "tuning"
        lines.append(f"| {k[0]} {k[1][0]},{k[1][1]} | {k[3]} | {held} | {s['tilt_deg']:.1f} | "
                     f"{s['metalness_mean']:.2f} | {ratio:.3f} | {'tripleplane' if flat else 'multiscale'} | "
                     f"{'yes' if good else 'no'} |")
    if not total:
        return f"no (crop, seed) pair ran both models under {variant!r}"
    lines += ["", f"The rule picks the better model on {right} of {total} pairs; its pick's mean FLIP over the "
                  f"better one's: mean {statistics.mean(regret):.3f}, worst {max(regret):.3f} (always the gated "
                  f"model: mean {statistics.mean(regret_gated):.3f}, worst {max(regret_gated):.3f})"]
    return "\n".join(lines)


def _cell(x: float | None) -> str:
    return "-" if x is None else f"{x:.2f}"


def ratio(crops: list[dict], rows: list[dict], variant: str, steps: int | None = None) -> str:
    """Per (crop, seed, model) that ran under `variant` at `steps`: its mean FLIP over tripleplane's at the default
    steps and, with `steps`, at the same steps; then per model the pairs above 1.5x."""
    at, _ = _index(crops, rows, steps)
    default, _ = _index(crops, rows)
    lines = ["| crop | seed | model | FLIP | / tripleplane (default steps) | / tripleplane (same steps) |",
             "|---|---|---|---|---|---|"]
    over: dict = {}
    for k, r in sorted(at.items(), key=lambda kv: (kv[0][2], kv[0][0], kv[0][1], kv[0][3])):
        if k[4] != variant or k[2] == "tripleplane":
            continue
        t_default = default.get((k[0], k[1], "tripleplane", k[3], variant))
        t_same = at.get((k[0], k[1], "tripleplane", k[3], variant)) if steps else t_default
        if t_default is None and t_same is None:
            continue
        r_default = _flip(r) / _flip(t_default) if t_default else None
        r_same = _flip(r) / _flip(t_same) if t_same else None
        n, worse = over.get(k[2], (0, 0))
        over[k[2]] = (n + 1, worse + (r_same is not None and r_same > 1.5))  # r_same is r_default without steps
        lines.append(f"| {k[0]} {k[1][0]},{k[1][1]} | {k[3]} | {k[2]} | {_flip(r):.4f} | {_cell(r_default)} | "
                     f"{_cell(r_same)} |")
    if not over:
        return f"no fit under {variant!r} at {steps or 'the default'} steps beside a tripleplane fit"
    lines += [""] + [f"{m}: above 1.5x tripleplane ({'same' if steps else 'default'} steps) on {w} of {n} pairs"
                     for m, (n, w) in over.items()]
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("crops")
    ap.add_argument("jobs", nargs="+")
    ap.add_argument("--against", action="append", default=[], help="BASE:VARIANT, e.g. lr1e-2:lr1e-2-precond0")
    ap.add_argument("--regime", action="append", default=[], help="variant label to score the rule under")
    ap.add_argument("--ratio", action="append", default=[], help="VARIANT[@STEPS]: every model's FLIP over "
                                                                 "tripleplane's")
    a = ap.parse_args()
    crops = json.load(open(a.crops))
    rows = [json.loads(line) for path in a.jobs for line in open(path) if line.strip()]
    for pair in a.against:
        base, _, variant = pair.partition(":")
        print(f"### {variant or 'the base recipe'} against {base or 'the base recipe'}\n")
        print(against(crops, rows, base, variant) + "\n")
    for variant in a.regime:
        print(f"### The texture-set default under {variant or 'the base recipe'}\n")
        print(regime(crops, rows, variant) + "\n")
    for spec in a.ratio:
        variant, _, steps = spec.partition("@")
        print(f"### Over tripleplane under {variant or 'the base recipe'} at {steps or 'the default'} steps\n")
        print(ratio(crops, rows, variant, int(steps) if steps else None) + "\n")


if __name__ == "__main__":
    main()
