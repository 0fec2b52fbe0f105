"""`neumat fit-many`: fit one or more models to every source of a material database, each (source, model) an
independent job (a Ray task), evaluated against its source; results.json + results.md; resumable."""
from __future__ import annotations

import os
import shlex
import sys
import time
from dataclasses import replace
from pathlib import Path

import typer

from ..core.errors import InputError
from .common import SEED_RANGE, THREADS_HELP, console, device_option, parse_overrides, run_command
from .fit_engines import RAY_HINT, RunProgress, check_ray_address, ray_available, run_local, run_ray
from .fit_job import FIT_KEYS, FitJob, run_fit_job, source_sha256
from .fit_results import is_done, is_fitted, markdown, read_rows, write_rows

#: source kinds fit-many fits (one Material per source)
KINDS = ("brdf", "svbrdf", "btf")


def register(app: typer.Typer) -> None:
    app.command("fit-many")(fit_many)


def fit_many(sources: list[str] = typer.Argument(..., help="material files, folders of them, .txt files listing "
                                                  "one source a line, or analytic specs"),
             model: list[str] = typer.Option(..., "--model", "-m", help="registered model; repeat for several "
                                                                       "(one row per source and model)"),
             set_: list[str] = typer.Option(None, "--set", help="key=value for every fit, as `neumat fit --set`; "
                                                               "MODEL:key=value for that model's fits only"),
             steps: int = typer.Option(None, min=0, help="optimiser steps (default: the recipe's)"),
             preset: list[str] = typer.Option(None, "--preset", help="a preset of every model (default: "
                                              "recommended, the best setting we measured; paper, cpu or one the "
                                              "model names, `neumat list MODEL`); MODEL:NAME for that model's fits "
                                              "only, e.g. --preset cpu --preset neubrdf:dense"),
             recipe_alias: list[str] = typer.Option(None, "--recipe", hidden=True, help="the old name of --preset"),
             seed: int = typer.Option(None, **SEED_RANGE, help="seed of every fit (default: the recipe's)"),
             device: str = typer.Option(None, callback=device_option,
                                       help="torch device of every fit (default: cuda if available, else cpu); "
                                            "with Ray, cuda asks one GPU per task"),
             source_option: list[str] = typer.Option(None, "--source-option", help="key=value for the source reader"),
             eval_n: int = typer.Option(2 ** 16, "--n-configs", "--eval-n", min=1,
                                        help="random (wi, wo) configurations of the reflectance errors, as `neumat "
                                             "eval --n-configs` (--eval-n: its old name)"),
             image_spp: int = typer.Option(16, "--image-spp", min=0, help="samples per pixel of the sphere "
                                                                         "renderings of the image metrics; 0: none"),
             image_resolution: int = typer.Option(64, "--image-resolution", min=8, help="rendering width and height"),
             engine: str = typer.Option("auto", help="ray: Ray tasks; local: one after another in this process; "
                                                     "auto: ray when Ray is installed, else local"),
             workers: int = typer.Option(None, min=1, help="CPUs of the local Ray instance (default: all)"),
             address: str = typer.Option(None, help="Ray cluster to run on (ray://host:10001, auto; default: "
                                                    "$RAY_ADDRESS, else a local instance)"),
             retries: int = typer.Option(2, min=0, help="times a task whose Ray worker died is run again"),
             threads: int = typer.Option(None, min=1, help=THREADS_HELP),
             reference_cache: Path = typer.Option(None, "--reference-cache",
                                                  help="folder that keeps each source's reference renderings of the "
                                                       "image metrics, for later runs and other processes (default: "
                                                       "OUT/reference-renders)"),
             quiet: bool = typer.Option(False, "--quiet", "-q", help="no line per job (the summary stays)"),
             out: Path = typer.Option(..., "-o", "--out", help="output folder: <source>.<model>.nmat "
                                                               "and .png, results.json, results.md")) -> None:
    """Fit every MODEL to every source as independent jobs (Ray tasks), evaluate each fitted model against its
    source (`neumat eval`'s reflectance errors and, with --image-spp > 0, sphere-image metrics), and write
    OUT/<source>.<model>.nmat, OUT/results.json (one row per source and model: source and its hash, model,
    recipe, metrics, bytes, fit seconds, device, worker, or the error that stopped it), OUT/results.md and, with
    --image-spp > 0, each fit's picture OUT/<source>.<model>.png (reference | model | FLIP error). A failing
    source gets its error row and the others go on. Run the same command again to resume: rows whose .nmat,
    source hash, options and the code's defaults (recipe contents, model config) match are kept, those whose
    evaluation options alone changed (--n-configs, --image-spp, --image-resolution) or whose picture is missing
    are evaluated again without refitting, the others (failed, new, changed) are fitted; a job stopped with its
    process (a killed run, a lost Ray worker) resumes its fit from its checkpoint, OUT/<source>.<model>.<key>.ckpt.
    Without Ray installed, --engine auto runs the jobs one after another here (install Ray: pip install
    'neumat\\[ray]').
    Exit code 1 when some job failed."""

    def go() -> bool:
        from ..catalog.open_material import material_source
        from ..models.registry import model_class
        from ..render.comparison import PROTOCOL

        if engine not in ("auto", "ray", "local"):
            raise InputError(f"--engine: expected auto, ray or local, got {engine!r}")
        use_ray = engine == "ray" or (engine == "auto" and ray_available())
        if engine == "ray" and not ray_available():
            raise InputError(f"--engine ray: Ray is not installed; {RAY_HINT}")
        if engine == "auto" and not use_ray:
            console.print(f"note: Ray is not installed, so the jobs run one after another in this process "
                          f"({RAY_HINT} to run them in parallel or on a cluster)", markup=False)
        for m in model:
            if model_class(m).source_kinds[0] not in KINDS:
                raise InputError(f"--model {m}: fit-many fits models of one material per source "
                                 f"({', '.join(KINDS)}), {m!r} fits {model_class(m).source_kinds[0]}")
        if out.exists() and not out.is_dir():
            raise InputError(f"-o/--out: {str(out)!r} is a file; expected a folder")
        named = source_names(expand_sources(sources))
        for s in named:
            material_source(s)  # a mistyped path is refused here, before any job or Ray starts
        if use_ray and (address or os.environ.get("RAY_ADDRESS")):
            check_ray_address(address or os.environ["RAY_ADDRESS"])
        out.mkdir(parents=True, exist_ok=True)
        overrides = model_overrides(parse_overrides(set_), model)
        presets = model_presets([*(recipe_alias or []), *(preset or [])], model)
        common = dict(out_dir=str(out), steps=steps, seed=seed, device=device,
                      source_options=parse_overrides(source_option, "--source-option"), eval_n=eval_n,
                      image_spp=image_spp, image_resolution=image_resolution, threads=threads,
                      reference_cache=str(reference_cache or out / "reference-renders"))
        jobs = [FitJob(source=s, name=n, model=m, overrides=overrides[m], preset=presets[m], **common)
                for s, n in named.items() for m in model]
        results = out / "results.json"
        previous = {(r["source"], r["model"]): r for r in read_rows(results)}
        rows, todo = {}, []
        for job in jobs:
            key = (job.source, job.model)
            try:
                sha = source_sha256(job.source)
                done, fitted = is_done(previous.get(key), job, sha), is_fitted(previous.get(key), job, sha)
            except OSError:
                done = fitted = False  # an unreadable source: its job reports the error
            if done:
                rows[key] = previous[key]
            else:
                todo.append(replace(job, evaluate_only=fitted))
        console.print(f"fit-many: {len(named)} source(s) x {len(model)} model(s) = {len(jobs)} job(s); "
                      f"{len(jobs) - len(todo)} already done (kept), {len(todo)} to fit"
                      + (f" ({sum(j.evaluate_only for j in todo)} of them fitted before: evaluated again)"
                         if any(j.evaluate_only for j in todo) else "") + " "
                      f"({'Ray' if use_ray else 'one after another in this process'})", highlight=False, soft_wrap=True)
        run = {"command": "neumat fit-many " + shlex.join(sys.argv[2:] if "fit-many" in sys.argv[1:2] else []),
               "engine": "ray" if use_ray else "local", "jobs": len(jobs), "fitted": len(todo),
               "evaluated_again": sum(j.evaluate_only for j in todo)}
        progress = RunProgress(len(todo), console, quiet=quiet)
        t0 = time.perf_counter()
        stream = (run_ray(todo, run_fit_job, progress, workers=workers, address=address, retries=retries,
                          gpus_per_task=1.0 if device and device.startswith("cuda") else 0.0,
                          log=lambda text: console.print(text, highlight=False, soft_wrap=True))
                  if use_ray else run_local(todo, run_fit_job, progress))
        ordered = []
        for row in stream:
            key = (row["source"], row["model"])
            if row["status"] == "ok" and key in previous and row["fit_sha256"] == previous[key].get("fit_sha256"):
                row |= {k: previous[key].get(k)
                        for k in FIT_KEYS if row.get(k) is None}  # evaluated again, not refitted
            rows[key] = row
            ordered = [rows[(j.source, j.model)] for j in jobs if (j.source, j.model) in rows]
            write_rows(results, ordered, run | {"wall_seconds": time.perf_counter() - t0})
        run["wall_seconds"] = time.perf_counter() - t0
        ordered = [rows[(j.source, j.model)] for j in jobs]
        write_rows(results, ordered, run)
        failed = [r for r in ordered if r["status"] != "ok"]
        notes = [f"`{run['command']}`", "",
                 f"{len(jobs)} job(s), {len(todo)} fitted or evaluated in this run ({run['engine']}, wall time "
                 f"{run['wall_seconds']:.1f} s), {len(failed)} failed. Metrics: reflectance errors over {eval_n} "
                 f"cosine-weighted (wi, wo)" + (f"; img_*: {image_resolution}^2 sphere renderings at {image_spp} "
                                                  f"spp, {PROTOCOL}" if image_spp else "")
                 + "; bytes at fp16; fit_s: training seconds."]
        (out / "results.md").write_text(markdown(ordered, f"fit-many: {len(named)} sources x {', '.join(model)}",
                                                 notes))
        console.print(f"wrote {out}/results.json and results.md: {len(ordered) - len(failed)} ok, {len(failed)} "
                      f"failed; {run['wall_seconds']:.1f} s", highlight=False, soft_wrap=True)
        for r in failed:
            console.print(f"  failed: {r['name']} ({r['model']}): {r['error']}", highlight=False, soft_wrap=True)
        return not failed

    if not run_command(go):
        raise typer.Exit(1)


def model_overrides(overrides: dict, models: list[str]) -> dict[str, dict]:
    """model -> its --set values: the plain keys, and "MODEL:key" for that model only (which wins)."""
    scoped = {k: k.partition(":")[0] for k in overrides if ":" in k}
    check_scopes("--set", scoped.values(), models)
    plain = {k: v for k, v in overrides.items() if k not in scoped}
    return {m: plain | {k.partition(":")[2]: v for k, v in overrides.items() if scoped.get(k) == m} for m in models}


def model_presets(values: list[str], models: list[str]) -> dict[str, str]:
    """model -> the preset its fits run: the default preset, or the last plain --preset value, or the last
    "MODEL:NAME" for that model (which wins); each checked against the model's presets."""
    from ..fit.preset import DEFAULT_PRESET, preset_named

    scoped = [v.partition(":") for v in values if ":" in v]
    check_scopes("--preset", (m for m, _, _ in scoped), models)
    plain = [v for v in values if ":" not in v]
    out = {}
    for m in models:
        out[m] = ([n for s, _, n in scoped if s == m] or plain or [DEFAULT_PRESET])[-1]
        preset_named(m, out[m])
    return out


def check_scopes(option: str, scopes, models: list[str]) -> None:
    """InputError naming the MODEL: scopes of `option` values that are not among the --model values."""
    unknown = sorted({m for m in scopes if m not in models})
    if unknown:
        raise InputError(f"{option}: {', '.join(unknown)} is not one of the --model values ({', '.join(models)})")


def expand_sources(items: list[str]) -> list[str]:
    """The sources the SOURCES arguments name, in order, without repeats: a folder's material files (sorted; the
    .json beside a same-named .h5 is that NBRDF network's architecture, not a source; a folder without any is
    itself one source, a texture set), the lines of a .txt file (blank lines and # comments skipped; relative
    paths from the file's folder), anything else as given (a file or a spec)."""
    from ..catalog.sources import file_suffixes

    suffixes = set(file_suffixes())
    out = []
    for item in items:
        path = Path(item)
        if path.is_dir():
            files = [p for p in sorted(path.iterdir()) if p.is_file() and p.suffix.lower() in suffixes
                     and not (p.suffix.lower() == ".json" and p.with_suffix(".h5").is_file())]
            out += [str(p) for p in files] or [item]
        elif path.suffix.lower() == ".txt":
            if not path.is_file():
                raise InputError(f"source list {item!r}: no such file")
            for line in path.read_text().splitlines():
                line = line.split("#", 1)[0].strip()
                if line:
                    listed = Path(line)
                    out.append(line if listed.is_absolute() or not (path.parent / listed).exists()
                               else str(path.parent / listed))
        else:
            out.append(item)
    if not out:
        raise InputError(f"no sources in {', '.join(items)}")
    return list(dict.fromkeys(out))


def source_names(sources: list[str]) -> dict[str, str]:
    """source -> its short name in outputs: the file stem (a spec: the spec with its ':=,/' as '_'); the file
    name where stems repeat, then the path (InputError if even those repeat)."""
    def short(s: str, level: int) -> str:
        p = Path(s)
        if level == 0:
            return p.stem if p.exists() else "".join("_" if c in ":=,/" else c for c in s)
        return p.name if level == 1 else "_".join(p.parts[-3:])

    names = {s: short(s, 0) for s in sources}
    for level in (1, 2):
        counts = {}
        for n in names.values():
            counts[n] = counts.get(n, 0) + 1
        names = {s: short(s, level) if counts[n] > 1 else n for s, n in names.items()}
    if len(set(names.values())) < len(names):
        raise InputError("sources with the same short name: " + ", ".join(s for s in names
                                                                         if list(names.values()).count(names[s]) > 1))
    return names
