"""The budget table of selection_free.md ("Where the CPU's time goes"): per first crop (seed 0) and model, the mean
FLIP over 9 scales and the fit's seconds at the old default (8-position targets, 1000 steps) beside the budget
variants (`--variant s256 --samples 256`, `--variant s32 --samples 32 --steps 4000 | 6000`, `--variant cosine`).

Usage: python -m benchmarks.studies.multiscale.selection_free_budget CROPS.json OLD_JOBS.jsonl BUDGET_JOBS.jsonl
"""
from __future__ import annotations

import argparse
import json

OLD_VARIANT = "lr1e-2-precond0-b09-ema02"
COLUMNS = ["8 x 1000 (old default)", "256 x 1000", "8 x 1000 cosine", "32 x 4000", "32 x 6000"]
MODELS = ["multiscale", "tripleplane", "neumip", "neumip-offset", "nbrdf-uv"]


def _rows(path: str) -> list[dict]:
    return [json.loads(line) for line in open(path) if line.strip()]


def table(crops: list[dict], old: list[dict], budget: list[dict]) -> str:
    """The Markdown table and a line on the budget runs' worst final / lowest loss and warnings."""
    first: dict = {}
    for c in crops:
        first.setdefault(c["name"], tuple(c["origin"]))
    cells = {}
    for r in old:
        if r["status"] == "ok" and r.get("variant") == OLD_VARIANT and not r.get("steps") and r["seed"] == 0:
            cells[(r["name"], tuple(r["origin"]), r["model"], COLUMNS[0])] = r
    label = {"s256": lambda r: "256 x 1000", "s32": lambda r: f"32 x {r.get('steps')}",
             "cosine": lambda r: "8 x 1000 cosine"}
    for r in budget:
        if r["status"] == "ok" and r.get("variant") in label and r["seed"] == 0:
            cells[(r["name"], tuple(r["origin"]), r["model"], label[r["variant"]](r))] = r
    lines = ["| crop (seed 0) | model | " + " | ".join(COLUMNS) + " |", "|---|---|" + "---|" * len(COLUMNS)]
    for name, origin in first.items():
        for model in MODELS:
            got = [cells.get((name, origin, model, c)) for c in COLUMNS]
            if sum(g is not None for g in got) < 2:
                continue
            lines.append(f"| {name} {origin[0]},{origin[1]} | {model} | " + " | ".join(
                "-" if g is None else f"{g['scales']['flip_mean']:.4f} ({g['fit_s']:.0f} s)" for g in got) + " |")
    runs = [r for k, r in cells.items() if k[3] != COLUMNS[0]]
    worst = max(r["final_loss"] / r["best_loss"] for r in runs)
    warned = sorted({f"{r['name']} {r['model']} {r['variant']}@{r.get('steps') or 1000}"
                     for r in runs if r.get("warning")})
    return ("\n".join(lines) + f"\n\nBudget runs: worst final / lowest loss {worst:.2f}; warned: "
            + (", ".join(warned) or "none"))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("crops")
    parser.add_argument("old_jobs")
    parser.add_argument("budget_jobs")
    a = parser.parse_args()
    print(table(json.load(open(a.crops)), _rows(a.old_jobs), _rows(a.budget_jobs)))


if __name__ == "__main__":
    main()
