"""`.nmat` model files: safetensors weights plus a JSON header.

The header is stored as the safetensors metadata entry "neumat":
  format "neumat-model", format_version (int; a reader refuses newer versions), type (registry name),
  config (the model's Config as a dict), runtime (whether `runtime()` was in effect: re-entered on load),
  recipe (the training Recipe as a dict, or null), source ({"name", "sha256"} or null), metrics (dict or
  null), size_bytes ({"fp16", "fp32"}), flops, neumat_version (informational: a warning when it differs).
The weights are the model's full `state_dict` (buffers included, e.g. pruning levels, frozen indices).

Loading is strict: an unknown type, unknown config or header keys, missing or unexpected weights, a wrong
shape, a newer format version or a truncated file raise DataFormatError naming the file.
"""
from __future__ import annotations

import hashlib
import json
import os
import warnings
from pathlib import Path
from typing import Any

import torch

from ..core.config import config_from_dict, config_to_dict
from ..core.errors import DataFormatError, InputError, NeumatError

FORMAT = "neumat-model"
FORMAT_VERSION = 1
HEADER_KEY = "neumat"
HEADER_FIELDS = ("format", "format_version", "type", "config", "runtime", "recipe", "source", "metrics",
                 "size_bytes", "flops", "neumat_version")


def model_config_class(cls: type) -> type:
    """The Config dataclass of model class `cls` (its `Config` attribute, else the type of a default
    instance's `cfg`)."""
    config = getattr(cls, "Config", None)
    return config if config is not None else type(cls().cfg)


def source_info(source: Any) -> dict:
    """{"name", "sha256"} of a training source: a file (hash of its bytes), a spec string (hash of the
    text) or a Material (hash of its float32 values at 4096 fixed queries)."""
    if isinstance(source, (str, Path)):
        path = Path(source)
        if path.is_file():
            h = hashlib.sha256()
            with open(path, "rb") as f:
                for block in iter(lambda: f.read(1 << 20), b""):
                    h.update(block)
            return {"name": path.name, "sha256": h.hexdigest()}
        return {"name": str(source), "sha256": hashlib.sha256(str(source).encode()).hexdigest()}
    if not callable(getattr(source, "eval", None)):
        raise InputError(f"save_model source: expected a file path, a spec or a Material, got {type(source).__name__}")
    from ..warp.uniform import uniform
    from ..core.query import Query
    from ..warp.hemisphere import sample_cosine_hemisphere
    from ..warp.sphere import sample_uniform_sphere
    gen = torch.Generator().manual_seed(0)
    u = uniform(4096, 6, gen, "cpu")
    warp = sample_uniform_sphere if getattr(source, "full_sphere", False) else sample_cosine_hemisphere
    q = Query(warp(u[:, :2]), warp(u[:, 2:4]), uv=u[:, 4:6] if getattr(source, "spatially_varying", False) else None)
    with torch.no_grad():
        values = source.eval(q).detach().to("cpu", torch.float32).contiguous()
    return {"name": source.describe(), "sha256": hashlib.sha256(values.numpy().tobytes()).hexdigest()}


def save_model(model, path: str | Path, *, recipe=None, source=None, metrics: dict | None = None) -> Path:
    """Write `model` to `path` (.nmat). recipe: the Recipe it was trained with; source: the training source
    (file path, spec string or Material); metrics: JSON-serialisable numbers measured at save time."""
    from ..core.version import __version__
    from ..models.registry import model_class

    path = Path(path)
    if path.suffix != ".nmat":
        raise InputError(f"save_model: model files end in .nmat, got {str(path)!r}")
    name = getattr(model, "name", None)
    if not isinstance(name, str) or not hasattr(model, "cfg") or not hasattr(model, "state_dict"):
        raise InputError(f"save_model: expected a registered neumat model (with name, cfg, state_dict), "
                         f"got {type(model).__name__}")
    if not isinstance(model, model_class(name)):
        raise InputError(f"save_model: model {name!r} is a {type(model).__name__}, not the registered "
                         f"{model_class(name).__name__}")
    header = {"format": FORMAT, "format_version": FORMAT_VERSION, "type": name, "config": config_to_dict(model.cfg),
              "runtime": bool(getattr(model, "is_runtime", False)),
              "recipe": config_to_dict(recipe) if recipe is not None else None,
              "source": source_info(source) if source is not None else None, "metrics": metrics,
              "size_bytes": {p: int(model.size_bytes(p)) for p in ("fp16", "fp32")}, "flops": int(model.flops()),
              "neumat_version": __version__}
    try:
        text = json.dumps(header, allow_nan=False)
    except (TypeError, ValueError) as e:
        raise InputError(f"save_model: metrics must be JSON-serialisable finite numbers ({e})") from None
    from safetensors.torch import save_file
    tensors = {k: v.detach().to("cpu").contiguous().clone() for k, v in model.state_dict().items()}
    tmp = path.with_name(path.name + ".tmp")
    save_file(tensors, str(tmp), metadata={HEADER_KEY: text})
    os.replace(tmp, path)
    return path


def read_header(path: str | Path) -> dict:
    """The checked JSON header of a .nmat file (without reading the weights)."""
    return _read(path, weights=False)[0]


def load_model(path: str | Path, device: str | torch.device | None = None):
    """The model stored in `path`, on `device` (default CPU), in eval mode (and in runtime mode if it was
    saved so)."""
    from ..models.registry import model_class

    header, tensors = _read(path, weights=True)
    where = f"model file {str(path)!r}"
    try:
        cls = model_class(header["type"])
    except NeumatError as e:
        raise DataFormatError(f"{where}: {e}") from None
    try:
        cfg = config_from_dict(model_config_class(cls), header["config"])
        model = cls(config=cfg)
    except InputError as e:
        raise DataFormatError(f"{where}: bad config for model {header['type']!r}: {e}") from None
    try:
        model.load_state_dict(tensors, strict=True)
    except RuntimeError as e:
        raise DataFormatError(f"{where}: weights do not match model {header['type']!r}: {e}") from None
    model.to(torch.device(device) if device is not None else "cpu")
    if header["runtime"]:
        if not callable(getattr(model, "runtime", None)):
            raise DataFormatError(f"{where}: saved in runtime mode, but model {header['type']!r} has no runtime()")
        model.runtime()
    model.train(False)
    return model


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
    from ..core.version import __version__

    if not isinstance(header, dict):
        raise DataFormatError(f"{where}: the header must be a JSON object")
    unknown = sorted(set(header) - set(HEADER_FIELDS))
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
