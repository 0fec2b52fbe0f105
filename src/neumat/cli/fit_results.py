"""`neumat fit-many`'s results: `results.json` (one row per (source, model), see `fit_job.ROW_KEYS`), which rows
a rerun may keep, and `results.md`, the rendered table."""
from __future__ import annotations

import json
import math
import statistics
from pathlib import Path

from ..core.errors import DataFormatError
from ..io.atomic import atomic_write
from .fit_job import FitJob, file_sha256, picture_path

#: metrics shown in results.md, in this order, where some row has them
TABLE_METRICS = ("rmse_hdr", "mae_hdr", "rel_err", "log_err", "img_mae", "img_rmse", "img_ssim", "img_flip",
                 "img_floor_mae", "img_floor_ssim")


def read_rows(path: Path) -> list[dict]:
    """The rows of an existing results.json ([] when there is none); DataFormatError for a file that is not one."""
    if not path.is_file():
        return []
    try:
        rows = json.loads(path.read_text())["rows"]
        if not all(isinstance(r, dict) and "name" in r and "model" in r for r in rows):
            raise ValueError("rows without name and model")
    except (ValueError, KeyError, TypeError) as e:
        raise DataFormatError(f"{str(path)!r} is not a fit-many results file ({e}); move it away to start afresh")
    return rows


def write_rows(path: Path, rows: list[dict], run: dict) -> None:
    """Write results.json: {"run": settings of the last run, "rows": rows}; NaN and inf as null."""
    text = json.dumps(_finite({"run": run, "rows": rows}), indent=1, allow_nan=False)
    atomic_write(path, lambda tmp: Path(tmp).write_text(text + "\n"))


def is_done(row: dict | None, job: FitJob, source_sha256: str) -> bool:
    """Whether `row` (from a previous run) already holds `job`: fitted and evaluated without error with the same
    options to a source of the same hash, its .nmat still the file it wrote, and its picture there when it is
    evaluated on images (a row made before pictures existed is evaluated again)."""
    picture = picture_path(job)
    return is_fitted(row, job, source_sha256) and row.get("options_sha256") == job.options_sha256() and (
        picture is None or (row.get("picture") == str(picture) and picture.is_file()))


def is_fitted(row: dict | None, job: FitJob, source_sha256: str) -> bool:
    """Whether `row` holds a model of `job` fitted with the same fit options (its evaluation may differ) to a
    source of the same hash, whose .nmat is still the file it wrote, and with the code's defaults of then (recipe
    contents, model Config): then only its evaluation needs redoing. Rows written before fit_sha256 existed are
    recognised by their options hash of that time."""
    if not row or row.get("status") != "ok":
        return False
    if row.get("fit_sha256") != job.fit_sha256() and row.get("options_sha256") != job.legacy_options_sha256():
        return False
    if row.get("source_sha256") != source_sha256 or not job.out.is_file():
        return False
    if "defaults_sha256" in row and row["defaults_sha256"] != job.defaults_sha256(row.get("device") or "cpu"):
        return False  # the code's defaults changed since (rows written before the hash existed are kept)
    return row.get("nmat_sha256") == file_sha256(job.out)


def markdown(rows: list[dict], title: str, notes: list[str]) -> str:
    """results.md: the notes, a table of every row (metrics, bytes, fit time, worker or the error) and the
    mean of each metric per model over its rows without error."""
    metrics = [m for m in TABLE_METRICS if any(m in (r.get("metrics") or {}) for r in rows)]
    head = ["source", "model", *metrics, "bytes_fp16", "fit_s", "device", "worker / error"]
    body = []
    for r in rows:
        m = r.get("metrics") or {}
        status = r["worker"] if r["status"] == "ok" else f"**{r['error']}**".replace("|", "\\|")
        body.append([r["name"], r["model"], *(_num(m.get(k)) for k in metrics), _int(r.get("bytes_fp16")),
                     _num(r.get("fit_seconds"), ".1f"), r.get("device") or "", status])
    lines = [f"# {title}", "", *notes, "", "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join(b) + " |" for b in body]
    means = ["| model | sources | failed | " + " | ".join(metrics) + " | bytes_fp16 | fit_s |",
             "|" + "---|" * (len(metrics) + 5)]
    for model in dict.fromkeys(r["model"] for r in rows):
        ok = [r for r in rows if r["model"] == model and r["status"] == "ok"]
        n = sum(r["model"] == model for r in rows)
        cells = [_mean([(r["metrics"] or {}).get(k) for r in ok]) for k in metrics]
        means.append(f"| {model} | {len(ok)} | {n - len(ok)} | " + " | ".join(_num(c) for c in cells) +
                     f" | {_int(_mean([r['bytes_fp16'] for r in ok]))}"
                     f" | {_num(_mean([r['fit_seconds'] for r in ok]), '.1f')} |")
    pictures = [f"![{r['name']} x {r['model']}]({Path(r['picture']).name})" for r in rows
                if r["status"] == "ok" and r.get("picture")]
    if pictures:
        pictures = ["", "## Pictures", "", "Each: the reference | the model | its FLIP error | the FLIP error of "
                    "the reference rendered like the model (the floor: what noise alone gives).", "", *pictures]
    return "\n".join(lines + ["", "## Mean per model (sources without error)", ""] + means + pictures) + "\n"


def _mean(values: list) -> float | None:
    vals = [v for v in values if v is not None and math.isfinite(v)]
    return statistics.fmean(vals) if vals else None


def _num(v, spec: str = ".4g") -> str:
    return "" if v is None else format(v, spec)


def _int(v) -> str:
    return "" if v is None else f"{round(v):,}"


def _finite(obj):
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_finite(v) for v in obj]
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj
