"""Safetensors files whose metadata holds one JSON header with a "type": the format of the SparseBTF
dictionary and of SH-PRT tables (model files have their own, stricter header: `neumat.io.modelfile`)."""
from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import torch

from ..core.errors import DataFormatError, InputError
from .atomic import atomic_write

#: metadata key of the JSON header
HEADER_KEY = "neumat"


def write_tagged(path: str | Path, tensors: dict[str, torch.Tensor], header: dict) -> Path:
    """Write copies of `tensors` (on the CPU) and `header` (a JSON object with a "type") to `path`."""
    from safetensors.torch import save_file

    copies = {k: v.detach().cpu().contiguous().clone() for k, v in tensors.items()}  # no shared storage
    return atomic_write(path, lambda tmp: save_file(copies, tmp, metadata={HEADER_KEY: json.dumps(header)}))


def read_tagged(path: str | Path, file_type: str, what: str) -> tuple[dict, dict[str, torch.Tensor]]:
    """(header, tensors) of a file `write_tagged` wrote with header type `file_type`. A missing file raises
    InputError; an unreadable one, or one of another type, DataFormatError naming `what` (e.g. "SH PRT")."""
    from safetensors import safe_open

    path = Path(path)
    if not path.is_file():
        raise InputError(f"{what} file {str(path)!r} does not exist")
    try:
        with safe_open(str(path), framework="pt") as f:
            header = json.loads((f.metadata() or {}).get(HEADER_KEY, "{}"))
            tensors = {k: f.get_tensor(k) for k in f.keys()}
    except Exception as e:  # safetensors raises its own error types for truncated / malformed files
        raise DataFormatError(f"{path}: not a readable {what} file: {type(e).__name__}: {e}") from None
    if not isinstance(header, dict) or header.get("type") != file_type:
        kind = header.get("type") if isinstance(header, dict) else None
        raise DataFormatError(f"{path}: header type {kind!r}, expected {file_type!r}")
    return header, tensors


def _number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


#: what `header_field` can ask for, and how to tell it (a JSON true is no number)
FIELD_KINDS = {
    "a positive integer": lambda v: isinstance(v, int) and not isinstance(v, bool) and v >= 1,
    "a non-negative integer": lambda v: isinstance(v, int) and not isinstance(v, bool) and v >= 0,
    "a finite number": _number,
    "a list of finite numbers": lambda v: isinstance(v, list) and all(_number(x) for x in v),
    "a string": lambda v: isinstance(v, str),
    "a JSON object": lambda v: isinstance(v, dict),
}


def header_field(header: dict, key: str, kind: str, where: str, **default: Any) -> Any:
    """header[key] when it is `kind` (a key of FIELD_KINDS); `default=...` stands in for a missing key.
    DataFormatError naming `where` ("FILE: header") and the field otherwise: a JSON value of the wrong type fails
    here, not deep in the reader with a traceback."""
    if key not in header and "default" in default:
        return default["default"]
    if key not in header:
        raise DataFormatError(f"{where} lacks the field {key!r} ({kind})")
    if not FIELD_KINDS[kind](header[key]):
        raise DataFormatError(f"{where} field {key!r} must be {kind}, got {header[key]!r}"[:300])
    return header[key]
