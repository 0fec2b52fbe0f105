"""Saving and loading models as `.nmat` files: the registered model class is built from the header that
`neumat.io.modelfile` reads and writes (format described there).

Loading is strict: an unknown type, unknown config or header keys, missing or unexpected weights, a wrong
shape, a newer format version or a truncated file raise DataFormatError naming the file. Model files written
with a model's old registry name load as the renamed model (`RENAMED_MODELS`).
"""
from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Any

import torch

from ..core.config import config_from_dict, config_to_dict
from ..core.errors import DataFormatError, InputError, NeumatError
from ..core.material import material_device
from ..core.query import Query
from ..core.version import __version__
from ..io.modelfile import FORMAT, FORMAT_VERSION, read_model_file, write_model_file
from ..models.registry import model_class
from ..warp.hemisphere import sample_cosine_hemisphere
from ..warp.sphere import sample_uniform_sphere
from ..warp.uniform import uniform

#: old registry name (still found in the "type" of older .nmat files) -> the model's current name
RENAMED_MODELS = {"zeltner": "neumip-frame"}  # the Zeltner-style baseline of Timonen et al. 2025, renamed


def source_info(source: Any) -> dict:
    """{"name", "sha256"} of a training source: a file (hash of its bytes), a folder such as a texture set (hash
    of its files' relative names and bytes, so an edited map is another source and a moved folder the same one), a
    spec string (hash of the text), a Material (hash of its float32 values at 4096 fixed queries) or a list of those
    (names joined, hash of their hashes)."""
    if isinstance(source, (list, tuple)):  # a set of sources fitted jointly
        parts = [source_info(s) for s in source]
        return {"name": " + ".join(p["name"] for p in parts),
                "sha256": hashlib.sha256("".join(p["sha256"] for p in parts).encode()).hexdigest()}
    if isinstance(source, (str, Path)):
        path = Path(source)
        if path.is_file():
            h = hashlib.sha256()
            with open(path, "rb") as f:
                for block in iter(lambda: f.read(1 << 20), b""):
                    h.update(block)
            return {"name": path.name, "sha256": h.hexdigest()}
        if path.is_dir():
            h = hashlib.sha256()
            for file in sorted(p for p in path.rglob("*") if p.is_file()):
                h.update(str(file.relative_to(path)).encode() + b"\0" + file.read_bytes())
            return {"name": path.name, "sha256": h.hexdigest()}
        return {"name": str(source), "sha256": hashlib.sha256(str(source).encode()).hexdigest()}
    if not callable(getattr(source, "eval", None)):
        raise InputError(f"save_model source: expected a file path, a spec or a Material, got {type(source).__name__}")
    gen = torch.Generator().manual_seed(0)
    u = uniform(4096, 6, gen, material_device(source))  # the same numbers on any device
    warp = sample_uniform_sphere if getattr(source, "full_sphere", False) else sample_cosine_hemisphere
    q = Query(warp(u[:, :2]), warp(u[:, 2:4]), uv=u[:, 4:6] if getattr(source, "spatially_varying", False) else None)
    with torch.no_grad():
        values = source.eval(q).detach().to("cpu", torch.float32).contiguous()
    return {"name": source.describe(), "sha256": hashlib.sha256(values.numpy().tobytes()).hexdigest()}


def save_model(model, path: str | Path, *, recipe=None, source=None, metrics: dict | None = None,
               preset: dict | None = None) -> Path:
    """Write `model` to `path` (.nmat). recipe: the Recipe it was trained with; source: the training source
    (file path, spec string or Material); metrics: JSON-serialisable numbers measured at save time; preset:
    {"name", "overrides"} of the preset the fit used."""
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
    if preset is not None:
        header["preset"] = preset
    tensors = {k: v.detach().to("cpu").contiguous().clone() for k, v in model.state_dict().items()}
    return write_model_file(path, header, tensors)


def _check_weights(expected: dict[str, torch.Tensor], stored: dict[str, torch.Tensor], where: str) -> None:
    """Refuse stored weights of the wrong kind (integers where the model holds floats, or the reverse; torch
    would cast them silently) or with NaN / infinite values. Missing, unexpected and mis-shaped weights are
    left to `load_state_dict`."""
    for name, t in stored.items():
        ref = expected.get(name)
        if ref is None:
            continue
        if t.is_floating_point() != ref.is_floating_point() or (t.dtype == torch.bool) != (ref.dtype == torch.bool):
            raise DataFormatError(f"{where}: weight {name!r} is stored as {t.dtype}, expected {ref.dtype}")
        if t.is_floating_point() and not bool(torch.isfinite(t).all()):
            raise DataFormatError(f"{where}: weight {name!r} has {int((~torch.isfinite(t)).sum())} NaN or infinite "
                                  "value(s) (a diverged training?); expected finite numbers")


def load_model(path: str | Path, device: str | torch.device | None = None):
    """The model stored in `path`, on `device` (default CPU), in eval mode (and in runtime mode if it was
    saved so)."""
    header, tensors = read_model_file(path)
    where = f"model file {str(path)!r}"
    try:
        cls = model_class(RENAMED_MODELS.get(header["type"], header["type"]))
    except NeumatError as e:
        raise DataFormatError(f"{where}: {e}") from None
    try:
        cfg = config_from_dict(cls.Config, header["config"])
        model = cls(config=cfg)
    except InputError as e:
        raise DataFormatError(f"{where}: bad config for model {header['type']!r}: {e}") from None
    except (TypeError, OverflowError) as e:  # a size of the right JSON type beyond what torch takes (1e30)
        raise DataFormatError(f"{where}: bad config for model {header['type']!r}: {type(e).__name__}: "
                              f"{str(e).splitlines()[0][:200]}") from None
    _check_weights(model.state_dict(), tensors, where)
    try:
        model.load_state_dict(tensors, strict=True)
    except RuntimeError as e:
        raise DataFormatError(f"{where}: weights do not match model {header['type']!r}: {e}") from None
    except InputError as e:  # a model's own check of what it loaded (e.g. NeuBRDF pruning levels)
        raise DataFormatError(f"{where}: {e}") from None
    model.to(torch.device(device) if device is not None else "cpu")
    if header["runtime"]:
        if not callable(getattr(model, "runtime", None)):
            raise DataFormatError(f"{where}: saved in runtime mode, but model {header['type']!r} has no runtime()")
        model.runtime()
    model.train(False)
    return model
