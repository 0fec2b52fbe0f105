"""`.nmat` model files: safetensors weights plus a JSON header (the format; building models from it is
`neumat.catalog.modelfile`).

The header is stored as the safetensors metadata entry "neumat":
  format "neumat-model", format_version (int; a reader refuses newer versions), type (registry name),
  config (the model's Config as a dict), runtime (whether `runtime()` was in effect: re-entered on load),
  recipe (the training Recipe as a dict, or null), source ({"name", "sha256"} or null), metrics (dict or
  null), size_bytes ({"fp16", "fp32"}), flops, neumat_version (informational: a warning when it differs);
  since format version 2 optionally preset ({"name", "overrides"}: the preset the fit used, `neumat.fit.preset`).
The weights are the model's full `state_dict` (buffers included, e.g. pruning levels, frozen indices).

Reading is strict: unknown header keys, a newer format version or a truncated file raise DataFormatError
naming the file; `neumat.catalog.modelfile.load_model` adds the checks of type, config and weights.
"""
from __future__ import annotations

import json
import warnings
from pathlib import Path
from typing import Any

import torch

from ..core.errors import DataFormatError, InputError
from ..core.version import __version__
from .atomic import atomic_write

FORMAT = "neumat-model"
FORMAT_VERSION = 2
HEADER_KEY = "neumat"
HEADER_FIELDS = ("format", "format_version", "type", "config", "runtime", "recipe", "source", "metrics",
                 "size_bytes", "flops", "neumat_version")
#: header fields a file may lack (older files do)
OPTIONAL_FIELDS = ("preset",)


def write_model_file(path: str | Path, header: dict, tensors: dict[str, torch.Tensor]) -> Path:
    """Write `header` (a JSON-serialisable dict, see the module docstring) and `tensors` to `path` (.nmat) through a
    temporary file, so that a crash leaves no half-written model. InputError if the header is not JSON (e.g.
    non-finite metrics)."""
    path = Path(path)
    try:
        text = json.dumps(header, allow_nan=False)
    except (TypeError, ValueError) as e:
        raise InputError(f"save_model: metrics must be JSON-serialisable finite numbers ({e})") from None
    from safetensors.torch import save_file
    return atomic_write(path, lambda tmp: save_file(tensors, tmp, metadata={HEADER_KEY: text}))


def read_header(path: str | Path) -> dict:
    """The checked JSON header of a .nmat file (without reading the weights)."""
    return _read(path, weights=False)[0]


def read_model_file(path: str | Path) -> tuple[dict, dict[str, torch.Tensor]]:
    """The checked JSON header and the weights (name -> CPU tensor) of a .nmat file."""
    return _read(path, weights=True)


def _read(path: str | Path, weights: bool) -> tuple[dict, dict]:
    from safetensors import SafetensorError, safe_open

    path = Path(path)
    where = f"model file {str(path)!r}"
    if not path.is_file():
        raise InputError(f"{where} does not exist")
    try:
        with safe_open(str(path), "pt", device="cpu") as f:
            meta = f.metadata() or {}
            tensors = {k: f.get_tensor(k) for k in f.keys()} if weights else {}
    except (SafetensorError, OSError, ValueError) as e:
        raise DataFormatError(f"{where}: not a readable .nmat file (truncated or not safetensors): {e}") from None
    if HEADER_KEY not in meta:
        raise DataFormatError(f"{where}: no neumat header (a safetensors file, but not a neumat model)")
    try:
        header = json.loads(meta[HEADER_KEY])
    except json.JSONDecodeError as e:
        raise DataFormatError(f"{where}: the header is not valid JSON ({e})") from None
    _check_header(header, where)
    return header, tensors


def _check_header(header: Any, where: str) -> None:
    if not isinstance(header, dict):
        raise DataFormatError(f"{where}: the header must be a JSON object")
    unknown = sorted(set(header) - set(HEADER_FIELDS) - set(OPTIONAL_FIELDS))
    missing = [k for k in HEADER_FIELDS if k not in header]
    if header.get("format") != FORMAT:
        raise DataFormatError(f"{where}: header format is {header.get('format')!r}, expected {FORMAT!r}")
    version = header.get("format_version")
    if isinstance(version, bool) or not isinstance(version, int) or version < 1:
        raise DataFormatError(f"{where}: format_version must be a positive integer, got {version!r}")
    if version > FORMAT_VERSION:
        raise DataFormatError(f"{where}: written with model-file format version {version} (neumat "
                              f"{header.get('neumat_version')}); this neumat {__version__} reads up to version "
                              f"{FORMAT_VERSION}: upgrade neumat")
    if unknown or missing:
        raise DataFormatError(f"{where}: header has unknown key(s) {unknown} / lacks {missing}")
    if not isinstance(header["type"], str) or not isinstance(header["config"], dict):
        raise DataFormatError(f"{where}: header 'type' must be a string and 'config' an object")
    if header["neumat_version"] != __version__:
        warnings.warn(f"{where} was written by neumat {header['neumat_version']}, this is {__version__}",
                      stacklevel=3)
