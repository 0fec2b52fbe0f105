"""What the quality suites share: fits through `neumat fit-many` (in this process), their rows as table rows, the
per-model summary with its seed spread, and budgets stated from the recipes themselves."""
from __future__ import annotations

import contextlib
import json
import statistics
import sys
from pathlib import Path
from typing import Callable

import numpy as np
import typer

from neumat.cli.main import app
from neumat.fit.method import recipe_for
from neumat.io.shared_data import shared_data_dir

from .. import harness

#: the fit-many metrics every quality table shows (image metrics under neumat.render.comparison's protocol)
METRICS = ("log_err", "rmse_hdr", "img_mae", "img_ssim", "img_flip", "img_floor_mae", "img_floor_ssim",
           "img_floor_flip")


def cli(args: list[str]) -> None:
    """Run a `neumat` command in this process, its output on stderr (stdout stays the suite's table or JSON). A
    failed command raises SystemExit with its exit status (its error line already printed), an interrupted one
    KeyboardInterrupt (typer returns status 130 for it): in this mode click returns a command's status instead of
    raising it, and a suite must not go on after a failed trace or fit."""
    with contextlib.redirect_stdout(sys.stderr):
        status = typer.main.get_command(app).main(list(args), prog_name="neumat", standalone_mode=False)
    if status == 130:
        raise KeyboardInterrupt
    if isinstance(status, int) and status != 0:
        raise SystemExit(status)


def fit_many(run: harness.Run, sources: list[str], models: list[str], options: list[str], seeds: list[int],
             after: Callable[[dict], dict] | None = None, made: dict[str, tuple[str, Callable[[], None]]] | None = None
             ) -> list[dict]:
    """fit-many's result rows of every (source, model) for each seed (a "seed" key added). Each is one job of the
    run (`harness.Run.job`): from the run's ledger when it holds it, else a `neumat fit-many` of that source and model
    alone (in a folder kept under --work when given), source after source so each source's reference images are
    rendered once; a job of another shard not in the ledger yet is left out. A failed job's row has status "error"
    and its message (never kept in the ledger: the next run tries again), and the run records it as skipped.
    `after(row)` runs on each fitted row while its .nmat exists (row["nmat"]); what it returns is added to the row.
    `made` names sources that are made on demand: {source: (what makes it, a text for the key; make())}, make()
    called before a job of that source runs (so jobs the ledger holds need no source), its text keying the job
    instead of the file's hash. Shards take the sources in a rotated order, so they make different ones first."""
    if run.work is not None:
        run.protocol["fits"] = ("fit-many folders kept under --work (a rerun resumes); wall and CPU seconds are "
                                "this sitting's, each row's 'fit s' its own fit's")  # no machine's folder in results
    from neumat.cli.fit_job import source_sha256  # of a file's bytes, a folder's files or a spec: never a path

    made = made or {}
    index, count = run.shard
    start = index * len(sources) // count
    order = sources[start:] + sources[:start]
    defaults_of = {model: method_key(model, options) for model in models}
    rows = {}
    for seed in seeds:
        for source in order:
            made_by, make = made.get(source, (None, None))
            source_key = source_sha256(source) if made_by is None else made_by
            for model in models:
                defaults = defaults_of[model]
                key = {"job": "fit-many", "source": Path(source).name, "source_sha256": source_key, "model": model,
                       "options": options, "seed": seed, **defaults}
                row = run.job(f"{Path(source).name} x {model} (seed {seed})", key,
                              lambda: (make and make()) or _fit_one(run, source, model, _own(options, model, models),
                                                                    seed, after, defaults),
                              keep=lambda r: r["status"] == "ok")
                if row is None:
                    continue
                if row["status"] != "ok":
                    run.skip(f"{row['name']} x {row['model']} (seed {seed})", str(row.get("error", row["status"])))
                rows[(seed, source, model)] = {**row, "seed": seed}
    return [rows[k] for k in ((seed, s, m) for seed in seeds for s in sources for m in models) if k in rows]


def fits_figure(run: harness.Run, rows: list[dict], source: str, models: list[str], options: list[str]) -> dict | None:
    """A table's figure (`harness.Run.table`): fit-many's picture of each of `models` fitted to `source` at the
    run's seed (reference | model | FLIP error | the floor's FLIP error, `neumat.viz.compare.comparison_picture`),
    one row each, from `fit_many(run, ..., models, options, ...)`'s `rows`. A job of the run (the ledger keeps the
    PNG), drawn once each of those fits is finished (in a shard, the last pass draws it): the pictures come from the
    fits' kept folders, where fit-many evaluates a fit again whose picture is missing and fits one that is gone.
    None while a fit is missing or failed."""
    from PIL import Image

    from neumat.cli.fit_job import source_sha256
    from neumat.viz.compare import BACKGROUND

    name = Path(source).name
    shown = {r["model"]: r for r in rows if r["seed"] == run.seed and Path(r["source"]).name == name}
    if sorted(shown) != sorted(models) or any(r["status"] != "ok" for r in shown.values()):
        return None
    defaults = {model: method_key(model, options) for model in models}

    def draw() -> dict:
        def picture(row: dict) -> dict:  # read while the fit's folder exists (a temporary one is removed after)
            return {"image": np.asarray(Image.open(row["picture"]).convert("RGB"))} if row.get("picture") else {}

        pictures = []
        for model in models:
            row = _fit_one(run, source, model, _own(options, model, models), run.seed, picture, defaults[model])
            if "image" not in row:
                return {"status": "error", "error": str(row.get("error") or "fit-many drew no picture")}
            pictures.append(row["image"])
        width = max(p.shape[1] for p in pictures)  # a picture kept from older code may be narrower: padded
        pictures = [np.pad(p, ((0, 0), (0, width - p.shape[1]), (0, 0)), constant_values=BACKGROUND[0])
                    for p in pictures]  # its grey
        return {"status": "ok", "png": harness.png_base64(np.concatenate(pictures, axis=0))}

    drawn = run.job(f"{name}: figure (seed {run.seed})",
                    {"job": "fit-many figure", "source": name, "source_sha256": source_sha256(source),
                     "models": models, "options": options, "seed": run.seed, "defaults": defaults},
                    draw, keep=lambda r: r["status"] == "ok")
    if drawn is None or drawn["status"] != "ok":
        if drawn is not None:
            run.skip(f"the figure of {name}", drawn["error"])
        return None
    return {"caption": f"{name}, seed {run.seed}, a row per model: the reference | the model | its FLIP error | the "
                       "FLIP error of the reference rendered like the model (the floor: what noise alone gives), "
                       "under the image protocol", "png": drawn["png"]}


def method_key(model: str, options: list[str]) -> dict:
    """What a fit of `model` with these CLI options takes from the code's defaults, for a job's key: the hash of the
    preset it names (`--preset`, else the default; `FitJob.fit_sha256`), that preset's overrides (fit_sha256 names
    "paper" and "cpu" only), the content of the model's CPU and paper recipes (a preset starts from one of them) and
    its config defaults, so a changed default fits again (a new config default, such as the gated model's
    `output_bound`, would otherwise leave every key as it was, and a rerun take the old fits from the ledger)."""
    from neumat.cli.fit_job import FitJob
    from neumat.core.config import config_to_dict
    from neumat.fit.preset import DEFAULT_PRESET, preset_named
    from neumat.models.registry import model_class

    preset = options[options.index("--preset") + 1] if "--preset" in options else DEFAULT_PRESET
    return {"preset": FitJob(source="", name="", model=model, out_dir="", preset=preset).fit_sha256(),
            "preset_overrides": preset_named(model, preset).contents(),
            "recipes": {name: config_to_dict(recipe_for(model, name)) for name in ("cpu", "paper")},
            "config": config_to_dict(model_class(model).Config())}


def _own(options: list[str], model: str, models: list[str]) -> list[str]:
    """`options` less the `--set OTHER:key=value` of the other models (fit-many refuses a model it does not fit)."""
    others = tuple(f"{m}:" for m in models if m != model)
    out, i = [], 0
    while i < len(options):
        if options[i] == "--set" and i + 1 < len(options) and options[i + 1].startswith(others):
            i += 2
            continue
        out.append(options[i])
        i += 1
    return out


def _fit_one(run: harness.Run, source: str, model: str, options: list[str], seed: int,
             after: Callable[[dict], dict] | None, defaults: dict) -> dict:
    """The fit-many row of `model` fitted to `source`, with `after`'s additions when it fitted. Its folder (kept
    under --work) is named by the code's `defaults` too (`method_key`): fit-many keeps a fit whose preset name and
    overrides match, so after a recipe's default changed the old folder would hand back the old fit."""
    shared = run.work or run.scratch  # the reference renderings, once for every job, seed and shard of the run
    cache = ["--reference-cache", str(shared / "reference-renders")] if shared is not None else []
    with run.folder("fit-many", source, model, options, seed, defaults) as out:
        try:
            cli(["fit-many", source, "-m", model, *options, "--seed", str(seed), "--threads", str(run.threads),
                 "--engine", "local", "-q", "-o", str(out), *cache])
        except SystemExit as stop:  # exit status 1: the job failed; its row says why
            if stop.code not in (0, 1, None):
                raise
        row = json.loads((Path(out) / "results.json").read_text())["rows"][0]
        return {**row, **after(row)} if row["status"] == "ok" and after is not None else row


def texture_set_fits(run: harness.Run, models: list[str], quick_models: list[str],
                     after: Callable[[dict], dict] | None = None, max_size: int | None = 256
                     ) -> tuple[list[dict], dict | None] | None:
    """fit-many rows of `models` on every shared texture set at each model's default preset, as `neumat fit` gives
    without flags (two seeds), each set read whole or, with `max_size`, downsampled to at most that many texels a
    side; or of `quick_models` on one set at 32^2 for 10 steps with 8-sample footprint targets in a quick run; with
    the figure of the first set (`fits_figure`); None (the run says why) without shared data. The default, not the
    paper's exact recipe (preset cpu): on these sets ggx-mipmap's paper loss diverges (loss 14-19x above its best,
    session 51)."""
    data = shared_data_dir()
    if data is None:
        run.skip("every fit", "no texture sets: shared data absent (neumat.io.shared_data)")
        return None
    sets = sorted(str(p) for p in (data / "svbrdf").iterdir() if p.is_dir())
    if run.quick:
        sets, models, seeds = sets[-1:], quick_models, [run.seed]
        options = ["--steps", "10", "--set", "batch_size=256", "--source-option", "max_size=32", "--source-option",
                   "samples=8", "--n-configs", "4096", "--image-spp", "2", "--image-resolution", "32"]
    else:
        size = [] if max_size is None else ["--source-option", f"max_size={max_size}"]
        options, seeds = [*size, "--n-configs", str(2 ** 18), "--image-spp", "64", "--image-resolution", "128"], \
            [run.seed, run.seed + 1]
    rows = fit_many(run, sets, models, options, seeds, after)
    return rows, fits_figure(run, rows, sets[0], models, options)


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


def default_budget(models: list[str]) -> str:
    """'model steps x batch' of each model's default preset on a CPU, with its targets' footprint samples where the
    preset sets them (option target_samples)."""
    from neumat.fit.preset import resolve_preset

    parts = []
    for m in models:
        r = resolve_preset(m, device="cpu").recipe
        samples = r.options.get("target_samples")
        parts.append(f"{m} {r.steps} x {r.batch_size}" + (f" ({samples}-sample targets)" if samples else ""))
    return "; ".join(parts)


def paper_budget(models: list[str]) -> str:
    """'model: steps x batch' of each model's paper recipe."""
    return "; ".join(f"{m} {recipe_for(m, 'paper').steps} x {recipe_for(m, 'paper').batch_size}" for m in models)
