"""What the quality suites share: fits through `neumat fit-many` (in this process), their rows as table rows, the
per-model summary with its seed spread, and budgets stated from the recipes themselves."""
from __future__ import annotations

import contextlib
import json
import statistics
import sys
from pathlib import Path
from typing import Callable

from neumat.cli.main import app
from neumat.fit.method import recipe_for
from neumat.io.shared_data import shared_data_dir

from .. import harness

#: the fit-many metrics every quality table shows (image metrics under neumat.render.comparison's protocol)
METRICS = ("log_err", "rmse_hdr", "img_mae", "img_ssim", "img_flip", "img_floor_mae", "img_floor_ssim",
           "img_floor_flip")


def cli(args: list[str]) -> None:
    """Run a `neumat` command in this process, its output on stderr (stdout stays the suite's table or JSON);
    SystemExit of a failed command propagates."""
    with contextlib.redirect_stdout(sys.stderr):
        app(args, standalone_mode=False)


def fit_many(run: harness.Run, sources: list[str], models: list[str], options: list[str], seeds: list[int],
             after: Callable[[dict], dict] | None = None) -> list[dict]:
    """fit-many's result rows of every (source, model) for each seed (a "seed" key added), `run.workers` fits at
    a time, in folders kept under --work when given (a rerun resumes: fit-many keeps what matches); a failed job's
    row has status "error" and its message, and the run records it as skipped. `after(row)` runs on each fitted row
    while its .nmat still exists (row["nmat"]); what it returns is added to the row."""
    rows = []
    engine = ["--engine", "local"] if run.workers == 1 else ["--engine", "ray", "--workers", str(run.workers)]
    if run.work is not None:
        run.protocol["fits"] = (f"fit-many folders kept under {run.work} (a rerun resumes); wall and CPU seconds are "
                                f"this sitting's, each row's 'fit s' its own fit's; {run.workers} fit(s) at a time")
    for seed in seeds:
        with run.folder("fit-many", sources, models, options, seed) as out:
            args = ["fit-many", *sources, *[a for m in models for a in ("-m", m)], *options, "--seed", str(seed),
                    "--threads", str(run.threads), *engine, "-q", "-o", str(out)]
            try:
                cli(args)
            except SystemExit as stop:  # exit status 1: some job failed; its row says why
                if stop.code not in (0, 1, None):
                    raise
            for row in json.loads((Path(out) / "results.json").read_text())["rows"]:
                if row["status"] != "ok":
                    run.skip(f"{row['name']} x {row['model']} (seed {seed})", str(row.get("error", row["status"])))
                elif after is not None:
                    row = {**row, **after(row)}
                rows.append({**row, "seed": seed})
    return rows


def texture_set_fits(run: harness.Run, models: list[str], quick_models: list[str],
                     after: Callable[[dict], dict] | None = None) -> list[dict] | None:
    """fit-many rows of `models` on every shared texture set at the paper's models' CPU path (256^2 texels, two
    seeds), or of `quick_models` on one set at 32^2 for 10 steps with 8-sample footprint targets in a quick run;
    None (the run says why) without shared data."""
    data = shared_data_dir()
    if data is None:
        run.skip("every fit", "no texture sets: shared data absent (neumat.io.shared_data)")
        return None
    sets = sorted(str(p) for p in (data / "svbrdf").iterdir() if p.is_dir())
    if run.quick:
        return fit_many(run, sets[-1:], quick_models,
                        ["--preset", "cpu", "--steps", "10", "--set", "batch_size=256", "--source-option",
                         "max_size=32", "--source-option", "samples=8", "--n-configs", "4096", "--image-spp", "2",
                         "--image-resolution", "32"],
                        [run.seed], after)
    return fit_many(run, sets, models, ["--preset", "cpu", "--source-option", "max_size=256", "--n-configs",
                                        str(2 ** 18), "--image-spp", "64", "--image-resolution", "128"],
                    [run.seed, run.seed + 1], after)


def quality_rows(rows: list[dict]) -> list[dict]:
    """One table row per fitted (source, model, seed): the METRICS, bytes and fit seconds."""
    return [{"source": r["name"], "model": r["model"], "seed": r["seed"],
             **{k: r["metrics"].get(k) for k in METRICS}, "bytes": r.get("bytes_fp16"),
             "fit s": r.get("fit_seconds")} for r in rows if r["status"] == "ok"]


def summary_rows(rows: list[dict], metrics: tuple[str, ...] = ("log_err", "img_mae", "img_ssim", "img_flip")) -> list[dict]:
    """Per model: each metric's mean over the sources for every seed, and the spread of those means over seeds
    (max - min: how far a rerun with another seed moves the number)."""
    out = []
    for model in dict.fromkeys(r["model"] for r in rows):
        per_seed = {}
        for r in rows:
            if r["model"] == model and r["status"] == "ok":
                per_seed.setdefault(r["seed"], []).append(r["metrics"])
        row = {"model": model, "seeds": len(per_seed), "sources": min((len(v) for v in per_seed.values()), default=0)}
        for k in metrics:
            means = [statistics.fmean(m[k] for m in ms) for ms in per_seed.values() if all(k in m for m in ms)]
            row[f"{k} mean"] = statistics.fmean(means) if means else None
            row[f"{k} seed spread"] = max(means) - min(means) if len(means) > 1 else None
        out.append(row)
    return out


def recipe_budget(models: list[str], steps: int | None = None) -> str:
    """'model steps x batch' of each model's CPU recipe, or with the given step count."""
    return "; ".join(f"{m} {steps or recipe_for(m, 'cpu').steps} x {recipe_for(m, 'cpu').batch_size}" for m in models)


def paper_budget(models: list[str]) -> str:
    """'model: steps x batch' of each model's paper recipe."""
    return "; ".join(f"{m} {recipe_for(m, 'paper').steps} x {recipe_for(m, 'paper').batch_size}" for m in models)
