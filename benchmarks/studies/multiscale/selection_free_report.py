"""Tables of the selection-free protocol (`selection_free.py`): per crop (its statistics, each model's mean FLIP
over the scale series per seed, the gated / tripleplane ratio), per model (stability: final / lowest loss), and the
gated model's win rate by regime."""
from __future__ import annotations

import statistics


def _key(r: dict) -> tuple:
    return r["name"], tuple(r["origin"])


def _run(r: dict) -> tuple:
    """What a row's fit was: (steps, variant), (0, "") for the default recipe."""
    return r.get("steps") or 0, r.get("variant") or ""


def _label(run: tuple) -> str:
    return " ".join([f"{run[0]} steps" if run[0] else "the recipe's steps", run[1]]).strip()


def report(crops: list[dict], rows: list[dict], a: str = "multiscale", b: str = "tripleplane") -> str:
    ok = [r for r in rows if r["status"] == "ok"]
    by = {}
    for r in ok:
        by.setdefault((_key(r), r["model"], _run(r)), {})[r["seed"]] = r
    lines = []
    for run in sorted({_run(r) for r in ok}, key=str):
        label = _label(run)
        table = [f"## {a} against {b}, {label}", "",
                 "| crop | tilt deg | rough mean | rough std | rank 1/4/16 | seed | " f"{a} FLIP | {b} FLIP | ratio |",
                 "|---|---|---|---|---|---|---|---|---|"]
        wins = total = 0
        ratios = []
        for c in crops:
            k = (c["name"], tuple(c["origin"]))
            ra, rb = by.get((k, a, run), {}), by.get((k, b, run), {})
            s = c["stats"]
            rank = "/".join(str(s["separability_rank"].get(f, "-")) for f in ("1", "4", "16"))
            for seed in sorted(set(ra) & set(rb)):
                fa, fb = ra[seed]["scales"]["flip_mean"], rb[seed]["scales"]["flip_mean"]
                wins += fa < fb
                total += 1
                ratios.append(fa / fb)
                table.append(f"| {c['name']} {c['origin'][0]},{c['origin'][1]} | {s['tilt_deg']:.1f} | "
                             f"{s['roughness_mean']:.2f} | {s['roughness_std']:.3f} | {rank} | {seed} | {fa:.4f} | "
                             f"{fb:.4f} | {fa / fb:.3f} |")
        if total:  # runs where only one of the two models ran get no table
            lines += table + ["", f"{a} below {b} on {wins} of {total} (crop, seed) pairs "
                                  f"({100 * wins / total:.0f} %); median ratio {statistics.median(ratios):.3f}", ""]
    lines += ["## Stability: final loss / lowest loss after the first 10 % of steps (worst per model)", "",
              "| model | fit | fits | worst final/lowest | at | warned fits |", "|---|---|---|---|---|---|"]
    for (model, run) in sorted({(r["model"], _run(r)) for r in ok}, key=str):
        rs = [r for r in ok if r["model"] == model and _run(r) == run]
        worst = max(rs, key=lambda r: r["final_loss"] / r["best_loss"])
        lines.append(f"| {model} | {_label(run)} | {len(rs)} | {worst['final_loss'] / worst['best_loss']:.2f} | "
                     f"{worst['name']} {worst['origin']} s{worst['seed']} | {sum(bool(r['warning']) for r in rs)} |")
    lines += ["", "## Every latent-texture model against tripleplane (mean FLIP ratio per crop and seed)", "",
              "| model | fit | pairs | median ratio | worst ratio | at | pairs above 1.5x |", "|---|---|---|---|---|---|---|"]
    for (model, run) in sorted({(r["model"], _run(r)) for r in ok if r["model"] != b}, key=str):
        rat = []
        for r in ok:
            if r["model"] != model or _run(r) != run:
                continue
            t = by.get((_key(r), b, run), {}).get(r["seed"])
            if t is not None:
                rat.append((r["scales"]["flip_mean"] / t["scales"]["flip_mean"], r))
        if rat:
            worst = max(rat, key=lambda x: x[0])
            lines.append(f"| {model} | {_label(run)} | {len(rat)} | {statistics.median(x[0] for x in rat):.3f} | "
                         f"{worst[0]:.2f} | {worst[1]['name']} {worst[1]['origin']} s{worst[1]['seed']} | "
                         f"{sum(x[0] > 1.5 for x in rat)} |")
    lines += _ordering(ok, by)
    lines += _against_default(ok, by)
    errors = [r for r in rows if r["status"] != "ok"]
    if errors:
        lines += ["", "Failed jobs: " + "; ".join(f"{r['name']} {r['origin']} {r['model']} s{r['seed']}: {r['error']}"
                                                   for r in errors)]
    return "\n".join(lines)


def _against_default(ok: list[dict], by: dict) -> list[str]:
    """Per model and fit kind other than the default recipe: its mean FLIP against the same model's at the default
    recipe on the same (crop, seed) pairs (the controlled experiments' table: a ratio below 1 is the variant
    better)."""
    out = []
    for (model, run) in sorted({(r["model"], _run(r)) for r in ok if _run(r) != (0, "")}, key=str):
        rat = [(r["scales"]["flip_mean"] / d["scales"]["flip_mean"], r) for r in ok
               if r["model"] == model and _run(r) == run
               and (d := by.get((_key(r), model, (0, "")), {}).get(r["seed"])) is not None]
        if not rat:
            continue
        if not out:
            out += ["", "## Each variant against the default recipe, same model, crop and seed (ratio of mean FLIP)",
                    "", "| model | fit | pairs | median ratio | better | best | worst | at |",
                    "|---|---|---|---|---|---|---|---|"]
        worst = max(rat, key=lambda x: x[0])
        out.append(f"| {model} | {_label(run)} | {len(rat)} | {statistics.median(x[0] for x in rat):.3f} | "
                   f"{sum(x[0] < 1 for x in rat)} | {min(x[0] for x in rat):.2f} | {worst[0]:.2f} | "
                   f"{worst[1]['name']} {worst[1]['origin']} s{worst[1]['seed']} |")
    return out


def _ordering(ok: list[dict], by: dict) -> list[str]:
    """Per fit kind: every model's mean FLIP averaged over the (crop, seed) pairs that every model of that kind ran,
    best first (the form of the paper's Table 6, on crops nobody chose); models with fewer than half the pairs of
    the most-run one are left out (named)."""
    out = []
    for run in sorted({_run(r) for r in ok}, key=str):
        count = {m: sum(1 for r in ok if _run(r) == run and r["model"] == m) for m in {r["model"] for r in ok}}
        most = max(count.values())
        models = sorted(m for m, n in count.items() if n and 2 * n >= most)
        partial = sorted(m for m, n in count.items() if n and 2 * n < most)
        if len(models) < 3:
            continue
        pairs = {(_key(r), r["seed"]) for r in ok if _run(r) == run}
        common = [p for p in pairs if all(p[1] in by.get((p[0], m, run), {}) for m in models)]
        if not common:
            continue
        means = {m: statistics.mean(by[(k, m, run)][s]["scales"]["flip_mean"] for k, s in common) for m in models}
        out += ["", f"## Every model, {_label(run)}: mean FLIP over the {len(common)} (crop, seed) pairs all ran", "",
                "| model | mean FLIP |", "|---|---|"]
        out += [f"| {m} | {v:.4f} |" for m, v in sorted(means.items(), key=lambda x: x[1])]
        if partial:
            out += ["", "Left out (fewer than half the pairs): " + ", ".join(f"{m} ({count[m]})" for m in partial)]
    return out
