"""One unit of `neumat fit-many`: fit one model to one source, save it, evaluate it against the source with
`neumat eval`'s metrics, and return its results row. Never raises: whatever stops the job (an unreadable file,
a non-finite fit, memory) becomes the row's "error", so one bad source cannot stop a database run."""
from __future__ import annotations

import fcntl
import hashlib
import json
import math
import os
import re
import socket
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

from ..core.errors import DataFormatError
from ..core.threads import shared_threads
from ..fit.preset import DEFAULT_PRESET

#: the row keys, in the order results.json and results.md show them
ROW_KEYS = ("name", "model", "status", "source", "source_sha256", "options_sha256", "fit_sha256", "defaults_sha256",
            "nmat", "nmat_sha256", "picture", "recipe", "metrics", "bytes_fp16", "file_bytes", "steps", "fit_seconds",
            "fit_cpu_seconds", "seconds", "cpu_seconds", "device", "worker", "warnings", "error")
#: the row keys an evaluation of an already fitted model takes over from the fit's row
FIT_KEYS = ("recipe", "steps", "fit_seconds", "fit_cpu_seconds", "warnings", "defaults_sha256")
#: version of the image metrics' protocol (`neumat.render.comparison`); part of the options hash, so rows
#: evaluated under an older protocol are evaluated again
IMAGE_PROTOCOL = ("sphere/sky, mis-lobes, sobol, model and floor against the reference at 16x spp, its Monte Carlo "
                  "footprint filter at 1/16 of its positions")


@dataclass(frozen=True)
class FitJob:
    """What to fit and how. source: a file path or spec (as `neumat fit` takes it); name: the source's short
    name (the model is saved as `out_dir/<name>.<model>.nmat`); overrides: `--set` values; eval_n: random (wi, wo)
    queries of the reflectance errors; image_spp / image_resolution: sphere renderings of both materials (image_spp 0:
    no image metrics); preset: a preset of the model (`neumat.fit.preset`); evaluate_only: the model
    at `out` was fitted with these fit options before: only evaluate it; threads: torch intra-op threads of the
    job (None: torch's default, all cores); reference_cache: a folder where the sources' reference renderings are
    kept (`reference_renders`). The last three are not part of the hashes."""

    source: str
    name: str
    model: str
    out_dir: str
    overrides: dict = field(default_factory=dict)
    steps: int | None = None
    seed: int | None = None
    device: str | None = None
    source_options: dict = field(default_factory=dict)
    eval_n: int = 2 ** 16
    image_spp: int = 16
    image_resolution: int = 64
    preset: str = DEFAULT_PRESET
    evaluate_only: bool = False
    threads: int | None = None
    reference_cache: str | None = None

    @property
    def out(self) -> Path:
        return Path(self.out_dir) / f"{self.name}.{self.model}.nmat"

    def fit_sha256(self) -> str:
        """Hash of everything that changes the fitted model (not its evaluation, the device nor the output)."""
        return _sha256(self._fit_options())

    def defaults_sha256(self, device: str) -> str:
        """Hash of what a fit on `device` takes from the code's defaults, not from its options: the contents of the
        recipe its preset resolves to there and the model's Config defaults. fit_sha256 names the preset only, so
        without this a resumed run would keep a fit made before a default changed (e.g. after an upgrade)."""
        from ..core.config import config_to_dict
        from ..fit.method import recipe_for
        from ..fit.preset import preset_named
        from ..models.registry import model_class

        kind = str(device).split(":")[0]
        recipe = preset_named(self.model, self.preset).recipe or ("cpu" if kind == "cpu" else "paper")
        return _sha256({"recipe": config_to_dict(recipe_for(self.model, recipe)),
                        "config": config_to_dict(model_class(self.model).Config())})

    def options_sha256(self) -> str:
        """Hash of everything that changes the fitted model or its metrics."""
        options = self._fit_options() | {k: getattr(self, k) for k in ("eval_n", "image_spp", "image_resolution")}
        if self.image_spp:
            options["image_protocol"] = IMAGE_PROTOCOL
        return _sha256(options)

    def legacy_options_sha256(self) -> str:
        """`options_sha256` as rows written before the image protocol was hashed (and before fit_sha256) hold."""
        return _sha256(self._fit_options() | {k: getattr(self, k) for k in ("eval_n", "image_spp", "image_resolution")})

    def _fit_options(self) -> dict:
        options = {k: asdict(self)[k] for k in ("model", "overrides", "steps", "seed", "source_options")}
        if self.preset != "paper":  # "recipe": the key of rows written before presets (the same names then)
            options["recipe"] = self.preset
            if self.preset != "cpu":
                from ..fit.preset import preset_named

                options["preset"] = preset_named(self.model, self.preset).contents()
                if not options["preset"]["by_recipe"]:  # rows written before by_recipe existed keep their key
                    del options["preset"]["by_recipe"]
        return options


def _sha256(options: dict) -> str:
    return hashlib.sha256(json.dumps(options, sort_keys=True, default=str).encode()).hexdigest()


def file_sha256(path: str | Path) -> str:
    """SHA-256 of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def source_sha256(source: str) -> str:
    """The hash `save_model` records for a source given as text: of the file's bytes, else of the spec."""
    from ..catalog.modelfile import source_info
    return source_info(source)["sha256"]


def run_fit_job(job: FitJob) -> dict:
    """Fit, save, reload and evaluate `job`; its row (ROW_KEYS) with status "ok", or "error" and the error
    (the .nmat of a failed job is removed). seconds / cpu_seconds: the job's wall and process CPU seconds (a
    process paused or sharing its cores shows in the first, not the second: estimates of a run's length read both)."""
    t0, cpu0 = time.perf_counter(), time.process_time()
    with shared_threads(job.threads):
        try:
            sha = source_sha256(job.source)
            row = error_row(job, None) | {"source_sha256": sha}
            row |= _fit_and_evaluate(job, sha) | {"status": "ok"}
        except Exception as e:  # noqa: BLE001 - every failure of one source becomes its row
            if not job.evaluate_only:  # an evaluation that failed keeps the model it could not evaluate
                job.out.unlink(missing_ok=True)
            _remove_checkpoints(job)  # a failed job is fitted from the start when run again
            row = error_row(job, e)
    row["seconds"], row["cpu_seconds"] = time.perf_counter() - t0, time.process_time() - cpu0
    return row


def error_row(job: FitJob, error: BaseException | None) -> dict:
    """The row of `job` before (error None) or instead of its results: status "error" and the error's type and
    last line (e.g. a Ray task lost with its worker), run by this process."""
    text = str(error).strip().splitlines() if error is not None else []
    message = f"{type(error).__name__}: {text[-1][:500] if text else ''}".rstrip(": ") if error is not None else None
    return {k: None for k in ROW_KEYS} | {"name": job.name, "model": job.model, "source": job.source,
                                          "status": "error", "error": message, "options_sha256": job.options_sha256(),
                                          "fit_sha256": job.fit_sha256(),
                                          "worker": f"{socket.gethostname()}:{os.getpid()}"}


def _fit_and_evaluate(job: FitJob, source_sha: str) -> dict:
    from ..catalog.modelfile import load_model, save_model
    from ..core.config import config_to_dict
    from ..fit.trainer import fit
    from ..fit.preset import build_fit
    from .fitting import open_training_source, resolve_device

    device = resolve_device(job.device)
    src = open_training_source(job.model, [job.source], job.source_options)
    picture = picture_path(job)
    if job.evaluate_only:
        fitted = load_model(job.out, device=device).runtime()  # files of older versions hold the training form
        return {"nmat": str(job.out), "nmat_sha256": file_sha256(job.out), "file_bytes": job.out.stat().st_size,
                "metrics": _checked(evaluate_against(fitted, src, job, device, picture), job),
                "picture": picture and str(picture), "bytes_fp16": int(fitted.size_bytes("fp16")),
                "device": str(device)}
    model, resolved = build_fit(job.model, job.preset, device=device, source=src, overrides=job.overrides,
                                seed=job.seed)
    checkpoint = checkpoint_path(job, device, source_sha)
    _remove_checkpoints(job, keep=checkpoint)  # of a job whose options, defaults or source have changed since
    result = fit(model, src, resolved.recipe, steps=job.steps, device=device, progress=False, checkpoint=checkpoint,
                 resume=True)
    loss = result.history[-1]["loss"] if result.history else None
    if loss is not None and not math.isfinite(loss):
        raise DataFormatError(f"fit of {job.model!r} to {job.source!r} ended with a non-finite loss ({loss})")
    save_model(result.model.runtime(), job.out, recipe=result.recipe, source=job.source,
               metrics={"final_loss": loss, "fit_seconds": result.seconds, "fit_cpu_seconds": result.cpu_seconds},
               preset={"name": resolved.preset, "overrides": resolved.applied})  # the shipped form, as `neumat fit`
    checkpoint.unlink(missing_ok=True)
    fitted = load_model(job.out, device=device)
    metrics = _checked(evaluate_against(fitted, src, job, device, picture), job)
    return {"nmat": str(job.out), "nmat_sha256": file_sha256(job.out), "picture": picture and str(picture),
            "file_bytes": job.out.stat().st_size,
            "recipe": config_to_dict(result.recipe), "defaults_sha256": job.defaults_sha256(str(device)),
            "metrics": metrics, "steps": result.steps,
            "bytes_fp16": int(fitted.size_bytes("fp16")), "fit_seconds": result.seconds,
            "fit_cpu_seconds": result.cpu_seconds, "device": str(device),
            "warnings": result.warnings}


def picture_path(job: FitJob) -> Path | None:
    """Where the job's picture goes (OUT/<source>.<model>.png: reference | model | FLIP error | the floor's FLIP
    error), when it is evaluated on images (image_spp > 0)."""
    return job.out.with_suffix(".png") if job.image_spp > 0 else None


def checkpoint_path(job: FitJob, device, source_sha: str) -> Path:
    """The file where the job's fit keeps its training state while it runs, so that a job stopped with its process
    (a session's end, a lost Ray worker, Ctrl-C) resumes where it was when run again: named by the job and by the
    hash of everything its fit takes (options, the code's defaults on `device`, the source's bytes: `source_sha`,
    its `source_sha256`), so a fit never resumes another's state. Removed when the job ends, fitted or failed."""
    key = _sha256({"fit": job.fit_sha256(), "defaults": job.defaults_sha256(str(device)), "source": source_sha})
    return Path(job.out_dir) / f"{job.name}.{job.model}.{key[:16]}.ckpt"


def _remove_checkpoints(job: FitJob, keep: Path | None = None) -> None:
    """Remove the job's checkpoints (`checkpoint_path`, any key) but `keep`."""
    folder, prefix = Path(job.out_dir), f"{job.name}.{job.model}."
    if folder.is_dir():
        for path in folder.iterdir():
            if path.name.startswith(prefix) and re.fullmatch(r"[0-9a-f]{16}\.ckpt", path.name[len(prefix):]) \
                    and path != keep:
                path.unlink(missing_ok=True)


def _checked(metrics: dict[str, float], job: FitJob) -> dict[str, float]:
    bad = sorted(k for k, v in metrics.items() if math.isnan(v))
    if bad:
        raise DataFormatError(f"model fitted to {job.source!r} has NaN metrics: {', '.join(bad)}")
    return metrics


def evaluate_against(model, reference, job: FitJob, device, picture: Path | None = None) -> dict[str, float]:
    """`neumat eval`'s quality metrics of `model` against `reference`: reflectance errors over `job.eval_n`
    cosine-weighted queries and, with `job.image_spp` > 0, image metrics of sphere renderings (img_*) with the
    reference's noise floor (img_floor_*, `neumat.render.comparison`), and then their picture written to `picture`
    (a PNG: `neumat.viz.compare.comparison_picture`), when given."""
    from ..metrics.hdr import reflectance_errors

    out = {k: float(v) for k, v in reflectance_errors(model, reference, n=job.eval_n, seed=0, device=device).items()}
    if job.image_spp > 0:
        from ..render.comparison import compared_images

        img, renders, test = compared_images(model, reference, job.image_spp, job.image_resolution, seed=0,
                                             device=device, renders=reference_renders_of(reference, job, device))
        out.update({f"img_{k}": float(v) for k, v in img.items()})
        if picture is not None:
            from PIL import Image

            from ..io.atomic import atomic_write
            from ..viz.compare import comparison_picture

            image = comparison_picture(renders, test, job.model, img)
            atomic_write(picture, lambda tmp: Image.fromarray(image).save(tmp, format="PNG"))
    return out


def reference_renders_of(reference, job: FitJob, device) -> tuple:
    """`neumat.render.comparison.reference_renders` of the job's source at its image settings: the last source's
    from this process's memory (the models of one source follow each other), else from job.reference_cache when it
    holds them, else rendered (and kept there). They dominate the evaluation of a fast model (a 256^2 texture set at
    128^2 and 64 spp: about 6 CPU minutes for the 16x reference and the floor), and shards of a benchmark run, its
    seeds and later runs with other models need the same renderings; processes sharing the folder render each once
    (a lock per file). The file is named by the source's hash and options, the settings, the device type
    and the code that renders and evaluates it."""
    import torch

    from ..io.atomic import atomic_write
    from ..render.comparison import reference_renders

    key = json.dumps([source_sha256(job.source), job.source_options, job.image_spp, job.image_resolution,
                      str(device).split(":")[0], _rendering_code_sha256(reference)], sort_keys=True, default=str)
    if _REFERENCE_RENDERS.get("key") == key:
        return _REFERENCE_RENDERS["renders"]

    def render() -> tuple:
        return reference_renders(reference, job.image_spp, job.image_resolution, 0, device)

    if job.reference_cache is None:
        renders = render()
    else:
        folder = Path(job.reference_cache)
        folder.mkdir(parents=True, exist_ok=True)
        path = folder / f"{hashlib.sha256(key.encode()).hexdigest()[:32]}.pt"
        with open(path.with_suffix(".lock"), "w") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            try:
                renders = tuple(torch.load(path, map_location="cpu", weights_only=True)) if path.is_file() else None
            except Exception:  # noqa: BLE001 - an unreadable cache file is rendered again and replaced
                renders = None
            if renders is None:
                renders = render()
                atomic_write(path, lambda tmp: torch.save([r.cpu() for r in renders], tmp))
        renders = tuple(r.to(device) for r in renders)
    _REFERENCE_RENDERS.clear()
    _REFERENCE_RENDERS.update(key=key, renders=renders)
    return renders


def _rendering_code_sha256(reference) -> str:
    """Hash of the renderer's source files (neumat/render/*.py) and of the modules of the reference's classes: a
    cached reference rendering is not reused by code that would render or evaluate it differently."""
    import inspect

    package = Path(__file__).parent.parent
    files = set((package / "render").glob("*.py"))
    for cls in type(reference).__mro__:
        path = Path(inspect.getfile(cls)) if cls.__module__.startswith("neumat.") else None
        if path is not None:
            files.add(path)
    h = hashlib.sha256()
    for path in sorted(files):
        h.update(str(path.relative_to(package)).encode() + b"\0" + path.read_bytes())
    return h.hexdigest()


#: the last source's reference renderings in this process (`reference_renders_of`)
_REFERENCE_RENDERS: dict = {}
