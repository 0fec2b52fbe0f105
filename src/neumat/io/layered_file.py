"""Layered material descriptions (`.json` with "type": "layered"): parsing and checking. The material
(`neumat.reflectance.layered.LayeredMaterial`) is built by `neumat.catalog.layered_file.read_layered`.

`read_description(path)` checks the top level and returns a `LayeredDescription`; `read_coat`, `read_sheen`
and `read_conductor` read the parts.

Details: docs/formats/layered_file.md, section `neumat.io.layered_file`.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from ..core.errors import InputError
from .images import read_image

_TOP_KEYS = {"type", "base", "max_size", "coats", "samples", "name", "sheen"}
_COAT_KEYS = {"eta", "roughness", "weight", "tint", "normal"}
_SHEEN_KEYS = {"color", "roughness", "weight"}
_CONDUCTOR_KEYS = {"conductor", "eta", "k", "roughness", "normal"}


@dataclass
class LayeredDescription:
    """The checked top level of a description: `spec` is the parsed JSON object, `folder` the directory its
    relative paths start from."""

    path: Path
    spec: dict
    folder: Path


@dataclass
class CoatDescription:
    """One coat: roughness and weight are floats or (H, W) maps; tint as written (the material checks it);
    normal (H, W, 3) unit vectors or None."""

    roughness: float | torch.Tensor
    weight: float | torch.Tensor
    eta: float
    tint: tuple
    normal: torch.Tensor | None


def _check_keys(d: dict, known: set, where: str) -> None:
    unknown = sorted(set(d) - known)
    if unknown:
        raise InputError(f"{where}: unknown key(s) {', '.join(unknown)} (known: {', '.join(sorted(known))})")


def _scalar_map(value, where: str, folder: Path, low: float | None, high: float | None,
                smudges: Callable[..., torch.Tensor]):
    """A number, or a map from {"smudges": {...}} / {"image": path} scaled to [low, high]."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return float(value)
    if not isinstance(value, dict):
        raise InputError(f"{where}: expected a number or an object with 'smudges' or 'image', got {value!r}")
    _check_keys(value, {"smudges", "image", "low", "high"}, where)
    lo, hi = value.get("low", low), value.get("high", high)
    if lo is None or hi is None:
        raise InputError(f"{where}: a map needs 'low' and 'high' (the values of mask 0 and 1)")
    if ("smudges" in value) == ("image" in value):
        raise InputError(f"{where}: give exactly one of 'smudges' and 'image'")
    if "smudges" in value:
        args = value["smudges"]
        if not isinstance(args, dict):
            raise InputError(f"{where} smudges: expected an object of smudge_map arguments, got {args!r}")
        try:
            mask = smudges(**args)
        except TypeError as e:
            raise InputError(f"{where} smudges: {e}") from None
    else:
        img = read_image(folder / value["image"], srgb=False)
        mask = torch.from_numpy(np.asarray(img, dtype=np.float32)).reshape(img.shape[0], img.shape[1], -1)
        mask = mask[..., :3].mean(-1).clamp(0, 1)
    return float(lo) + (float(hi) - float(lo)) * mask


def _normal_map(path, where: str, folder: Path) -> torch.Tensor:
    img = np.asarray(read_image(folder / str(path), srgb=False), dtype=np.float32)
    if img.ndim != 3 or img.shape[2] < 3:
        raise InputError(f"{where}: {path} is not an RGB normal map (shape {img.shape})")
    n = torch.from_numpy(img[..., :3] * 2 - 1)
    return n / n.norm(dim=-1, keepdim=True).clamp(min=1e-6)


def read_description(path: str | Path) -> LayeredDescription:
    """The parsed and checked top level of a description file (module docstring); coats are read by `read_coat`."""
    path = Path(path)
    try:
        spec = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise InputError(f"{path}: not a readable JSON layered-material description ({e})") from None
    if not isinstance(spec, dict) or spec.get("type") != "layered":
        raise InputError(f"{path}: expected a JSON object with \"type\": \"layered\"")
    _check_keys(spec, _TOP_KEYS, str(path))
    if "base" not in spec or not isinstance(spec.get("coats", []), list) or \
            (not spec.get("coats") and "sheen" not in spec):
        raise InputError(f"{path}: needs a 'base' material and a non-empty 'coats' list (or a 'sheen')")
    for key in ("max_size", "samples"):
        if key in spec and (isinstance(spec[key], bool) or not isinstance(spec[key], int) or spec[key] < 1):
            raise InputError(f"{path}: '{key}' must be a positive integer, got {spec[key]!r}")
    return LayeredDescription(path, spec, path.parent)


def read_coat(c, where: str, folder: Path, smudges: Callable[..., torch.Tensor]) -> CoatDescription:
    """Coat object `c` of a description (`where` names it in errors); smudge masks come from
    `smudges(**arguments)` (`neumat.reflectance.smudge_map.smudge_map`)."""
    if not isinstance(c, dict):
        raise InputError(f"{where}: expected an object, got {c!r}")
    _check_keys(c, _COAT_KEYS, where)
    if "roughness" not in c:
        raise InputError(f"{where}: needs a 'roughness' (GGX alpha)")
    return CoatDescription(roughness=_scalar_map(c["roughness"], f"{where} roughness", folder, None, None, smudges),
                           weight=_scalar_map(c.get("weight", 1.0), f"{where} weight", folder, 0.0, 1.0, smudges),
                           eta=c.get("eta", 1.5), tint=c.get("tint", (1.0, 1.0, 1.0)),
                           normal=None if c.get("normal") is None else _normal_map(c["normal"], where, folder))


@dataclass
class SheenDescription:
    """The sheen: colour as written (the material checks it); roughness and weight floats or (H, W) maps."""

    color: tuple
    roughness: float | torch.Tensor
    weight: float | torch.Tensor


def read_sheen(c, where: str, folder: Path, smudges: Callable[..., torch.Tensor]) -> SheenDescription:
    """The "sheen" object `c` of a description (module docstring)."""
    if not isinstance(c, dict):
        raise InputError(f"{where}: expected an object, got {c!r}")
    _check_keys(c, _SHEEN_KEYS, where)
    return SheenDescription(color=tuple(c.get("color", (1.0, 1.0, 1.0))),
                            roughness=_scalar_map(c.get("roughness", 0.3), f"{where} roughness", folder, None, None,
                                                  smudges),
                            weight=_scalar_map(c.get("weight", 1.0), f"{where} weight", folder, 0.0, 1.0, smudges))


@dataclass
class ConductorDescription:
    """A conductor base: a preset name or eta and k as written; roughness a float or (H, W) map; normal
    (H, W, 3) or None."""

    material: str | None
    eta: object
    k: object
    roughness: float | torch.Tensor
    normal: torch.Tensor | None


def read_conductor(c: dict, where: str, folder: Path, smudges: Callable[..., torch.Tensor]) -> ConductorDescription:
    """A base object with "conductor" or "eta" and "k" (module docstring)."""
    _check_keys(c, _CONDUCTOR_KEYS, where)
    if ("conductor" in c) == ("eta" in c or "k" in c):
        raise InputError(f"{where}: give either 'conductor' (a preset name) or both 'eta' and 'k'")
    return ConductorDescription(material=c.get("conductor"), eta=c.get("eta"), k=c.get("k"),
                                roughness=_scalar_map(c.get("roughness", 0.2), f"{where} roughness", folder, None,
                                                      None, smudges),
                                normal=None if c.get("normal") is None else _normal_map(c["normal"], where, folder))
