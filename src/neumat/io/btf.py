"""BTF files: the neumat `.nbtf` format (reader and writer); Bonn / UBO2014 `.btf` files: `neumat.io.ubo2014`.

`.nbtf` layout (a safetensors container, so any safetensors reader can open it):

- metadata key ``neumat_btf``: a JSON object with ``format = "neumat-btf"``, ``version = 1``,
  ``height``, ``width``, ``n_light``, ``n_view``, ``channels = "RGB"``, ``dtype`` ("float16" or "float32"),
  ``quantity`` (apparent BRDF, linear RGB, cosine excluded), ``uv`` (texel-centre convention), ``label``,
  ``clamped`` (number of values clamped to the float16 range on writing) and a free ``extra`` object;
- tensors ``light_dirs (L, 3)`` and ``view_dirs (V, 3)`` float32 unit vectors (z = macro normal);
- one chunk per light direction, ``light_00000 ... light_{L-1}``, each ``(V, H, W, 3)`` in ``dtype``.

Chunks are read lazily, so `read_btf_table(path, lights=[...])` loads a subset of light directions. The readers
return a plain `BTFTable`; `neumat.reflectance.btf.read_btf` builds the `TabulatedBTF` material from it.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import torch

from ..core.errors import DataFormatError, InputError
from .atomic import atomic_write
from .tagged_file import header_field

FORMAT = "neumat-btf"
VERSION = 1
FP16_MAX = 65504.0


@dataclass
class BTFTable:
    """A BTF table as read from a file: data (L, V, H, W, 3) apparent BRDF values (linear RGB, cosine excluded),
    light_dirs (L, 3) and view_dirs (V, 3) unit vectors (z = macro normal), and a label."""

    data: torch.Tensor
    light_dirs: torch.Tensor
    view_dirs: torch.Tensor
    label: str


def _chunk(i: int) -> str:
    return f"light_{i:05d}"


def write_btf(path: str | Path, btf, dtype: str = "float16", extra: dict | None = None) -> Path:
    """Write `btf` (a `BTFTable` or anything with its fields, e.g. a `TabulatedBTF`) as a `.nbtf` file; values
    beyond the float16 range are clamped (and counted). InputError for NaN, infinite or negative values (a BTF
    value is a ratio of radiance to irradiance: readers refuse them too)."""
    from safetensors.torch import save_file

    if dtype not in ("float16", "float32"):
        raise InputError(f"write_btf dtype: expected 'float16' or 'float32', got {dtype!r}")
    path = Path(path)
    data = btf.data.detach().cpu()
    _check_values(data, f"write_btf {str(path)!r}", InputError)
    l, v, h, w, _ = data.shape
    clamped = 0
    tensors = {"light_dirs": btf.light_dirs.detach().cpu().float().clone(),
               "view_dirs": btf.view_dirs.detach().cpu().float().clone()}
    for i in range(l):
        chunk = data[i].float()
        if dtype == "float16":
            clamped += int((chunk.abs() > FP16_MAX).sum())
            chunk = chunk.clamp(-FP16_MAX, FP16_MAX).half()
        tensors[_chunk(i)] = chunk.contiguous()
    header = {"format": FORMAT, "version": VERSION, "height": h, "width": w, "n_light": l, "n_view": v,
              "channels": "RGB", "dtype": dtype,
              "quantity": "apparent BRDF: radiance / (perpendicular irradiance * cos theta_light), linear RGB",
              "uv": "texel (row i, col j) centre at uv = ((j + 0.5) / W, 1 - (i + 0.5) / H)",
              "label": btf.label, "clamped": clamped, "extra": extra or {}}
    return atomic_write(path, lambda tmp: save_file(tensors, tmp, metadata={"neumat_btf": json.dumps(header)}))


def read_btf_header(path: str | Path) -> dict:
    """The JSON header of a `.nbtf` file (validated)."""
    from safetensors import safe_open

    path = _existing(path)
    try:
        with safe_open(str(path), framework="pt") as f:
            meta = f.metadata() or {}
            keys = set(f.keys())
    except Exception as e:  # safetensors raises its own error types for truncated / malformed files
        raise DataFormatError(f"{path}: not a readable .nbtf (safetensors) file: {e}") from None
    return _validate_header(path, meta, keys)


def read_btf_table(path: str | Path, device=None, lights: list[int] | None = None) -> BTFTable:
    """Read a `.nbtf` file as a float32 `BTFTable` on `device` (optionally only some light slices).
    DataFormatError when a chunk's shape or dtype differs from the header, a value is NaN, infinite or
    negative, or a direction is not a finite unit vector."""
    from safetensors import safe_open

    header = read_btf_header(path)
    n_l, n_v, h, w = header["n_light"], header["n_view"], header["height"], header["width"]
    sel = list(range(n_l)) if lights is None else list(lights)
    bad = [i for i in sel if not 0 <= i < n_l]
    if bad:
        raise InputError(f"read_btf lights: indices {bad} outside 0..{n_l - 1}")
    try:
        with safe_open(str(path), framework="pt") as f:
            light_dirs = f.get_tensor("light_dirs")
            view_dirs = f.get_tensor("view_dirs")
            chunks = [f.get_tensor(_chunk(i)) for i in sel]
    except Exception as e:
        raise DataFormatError(f"{path}: cannot read BTF chunks (truncated or corrupt file?): {e}") from None
    if tuple(light_dirs.shape) != (n_l, 3) or tuple(view_dirs.shape) != (n_v, 3):
        raise DataFormatError(f"{path}: header says {n_l} light and {n_v} view directions, but the direction lists "
                              f"have shapes {tuple(light_dirs.shape)} and {tuple(view_dirs.shape)}")
    for name, dirs in (("light_dirs", light_dirs), ("view_dirs", view_dirs)):
        norm = dirs.double().norm(dim=-1)
        if not dirs.is_floating_point() or not bool(((norm - 1).abs() <= 1e-3).all()):  # NaN fails too
            raise DataFormatError(f"{path}: {name} must hold finite float unit vectors, got {dirs.dtype} ones with "
                                  f"norms in [{float(norm.min()):.4g}, {float(norm.max()):.4g}]")
    for i, c in zip(sel, chunks):
        if tuple(c.shape) != (n_v, h, w, 3):
            raise DataFormatError(f"{path}: chunk {_chunk(i)} has shape {tuple(c.shape)}, expected {(n_v, h, w, 3)} "
                                  "from the header")
        if str(c.dtype).removeprefix("torch.") != header.get("dtype"):
            raise DataFormatError(f"{path}: chunk {_chunk(i)} is {str(c.dtype).removeprefix('torch.')}, but the "
                                  f"header says dtype {header.get('dtype')!r}")
    data = torch.stack(chunks).to(device=device, dtype=torch.float32)
    _check_values(data, str(path), DataFormatError)
    return BTFTable(data, light_dirs[sel].to(device), view_dirs.to(device), label=header.get("label", Path(path).stem))


def _check_values(data: torch.Tensor, where: str, error: type) -> None:
    """Raise `error` naming `where` when `data` holds NaN, infinite or negative values."""
    bad = int((~torch.isfinite(data)).sum())
    if bad:
        raise error(f"{where}: {bad} BTF value(s) are NaN or infinite; expected finite values >= 0")
    negative = int((data < 0).sum())
    if negative:
        raise error(f"{where}: {negative} BTF value(s) are negative (min {float(data.min()):.4g}); expected "
                    "values >= 0 (radiance / irradiance)")


def _existing(path: str | Path) -> Path:
    path = Path(path)
    if not path.is_file():
        raise InputError(f"BTF file {str(path)!r} does not exist")
    return path


def _validate_header(path: Path, meta: dict, keys: set[str]) -> dict:
    if "neumat_btf" not in meta:
        raise DataFormatError(f"{path}: no 'neumat_btf' header; not a neumat BTF file")
    try:
        header = json.loads(meta["neumat_btf"])
    except json.JSONDecodeError as e:
        raise DataFormatError(f"{path}: malformed 'neumat_btf' header ({e})") from None
    if not isinstance(header, dict):
        raise DataFormatError(f"{path}: the 'neumat_btf' header must be a JSON object")
    if header.get("format") != FORMAT:
        raise DataFormatError(f"{path}: header format {header.get('format')!r}, expected {FORMAT!r}")
    if isinstance(header.get("version"), bool) or header.get("version") != VERSION:
        raise DataFormatError(f"{path}: header version {header.get('version')!r}, this reader knows {VERSION}")
    for k in ("height", "width", "n_light", "n_view"):
        header_field(header, k, "a positive integer", f"{path}: header")
    if header.get("dtype") not in ("float16", "float32"):
        raise DataFormatError(f"{path}: header dtype {header.get('dtype')!r}, expected 'float16' or 'float32'")
    header_field(header, "label", "a string", f"{path}: header", default=None)
    header_field(header, "extra", "a JSON object", f"{path}: header", default=None)
    header_field(header, "clamped", "a non-negative integer", f"{path}: header", default=None)
    chunks = {k for k in keys if k.startswith("light_") and k != "light_dirs"}
    if len(chunks) != header["n_light"] or chunks != {_chunk(i) for i in range(header["n_light"])}:
        raise DataFormatError(f"{path}: header says {header['n_light']} light directions but the file has "
                              f"{len(chunks)} light chunks")
    for k in ("light_dirs", "view_dirs"):
        if k not in keys:
            raise DataFormatError(f"{path}: missing tensor {k!r}")
    return header


__all__ = ["BTFTable", "write_btf", "read_btf_table", "read_btf_header"]
