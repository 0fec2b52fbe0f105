"""`describe(name)`: what a material file or spec holds — kind, resolution, value range, validity, size.

Used by `neumat data info`. Every reader raises `DataFormatError` on a broken file (a truncated file, NaN
values, a VNDF without mass, a model whose weights are missing, mis-shaped or NaN, ...), and `describe` reads
each file whole (a model file is loaded, weights and all), so a file that `describe` accepts is also one the
package can evaluate.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..core.errors import InputError
from ..core.query import Query
from ..io.shared_data import resolve_data_path
from .open_material import open_material

#: image suffixes `describe` reports on
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".exr", ".hdr")


def describe(name: str | Path) -> dict[str, Any]:
    """A flat dict of facts about the file or analytic spec `name` (see the module docstring)."""
    path = resolve_data_path(str(name))  # also inside $NEUMAT_SHARED_DATA
    suffix = path.suffix.lower()
    if path.exists() and not path.is_file():
        raise InputError(f"{name}: is a directory, expected a material file or image")
    if suffix == ".binary":
        return _describe_merl(path)
    if suffix == ".bsdf":
        return _describe_rgl(path)
    if suffix == ".nmat":
        return _describe_model(path)
    if suffix == ".nbtf":
        return _describe_btf(path)
    if suffix in IMAGE_SUFFIXES:
        return _describe_image(path)
    material = open_material(str(name))  # analytic spec, other material file, or a clear error
    kind = f"material file ({suffix or 'folder'})" if path.exists() else "analytic material"
    return {"kind": kind, "material": material.describe(), "can_sample": material.can_sample,
            **_sampled_range(material)}


def _on_disk(path: Path) -> dict[str, Any]:
    return {"file": str(path), "size_on_disk_bytes": path.stat().st_size}


def _describe_merl(path: Path) -> dict[str, Any]:
    from ..io.merl import MERL_SCALE, identify_merl, read_merl

    table = read_merl(path).table
    scaled = table * np.asarray(MERL_SCALE).reshape(3, 1, 1, 1)
    missing = table < 0
    finite = np.isfinite(table)
    valid = finite & ~missing
    return {"kind": "MERL measured BRDF (.binary)", **_on_disk(path),
            "resolution": "theta_h 90 x theta_d 90 x phi_d 180, RGB",
            "identified_as": identify_merl(path) if _hash_list_present() else "unknown (hash list absent)",
            "value_min": float(scaled[valid].min()) if valid.any() else math.nan,
            "value_max": float(scaled[valid].max()) if valid.any() else math.nan,
            "missing_entries": int(missing.sum()), "missing_fraction": round(float(missing.mean()), 6),
            "non_finite_entries": int((~finite).sum()), "valid": bool(finite.all()) and bool(valid.any())}


def _hash_list_present() -> bool:
    from ..io.merl import MERL_HASH_LIST
    return MERL_HASH_LIST.is_file()


def _describe_rgl(path: Path) -> dict[str, Any]:
    from ..io.rgl import read_rgl

    data = read_rgl(path)
    f = data.fields
    rgb = f["rgb"]
    finite = np.isfinite(rgb)
    return {"kind": "RGL measured BRDF (.bsdf tensor file)", **_on_disk(path),
            "description": data.description.strip().splitlines()[0] if data.description.strip() else "",
            "isotropic": data.isotropic,
            "resolution": f"{f['phi_i'].shape[0]} phi_i x {f['theta_i'].shape[0]} theta_i x "
                          f"{rgb.shape[3]} x {rgb.shape[4]} RGB samples",
            "value_min": float(rgb[finite].min()), "value_max": float(rgb[finite].max()),
            "negative_entries": int((rgb[finite] < 0).sum()), "non_finite_entries": int((~finite).sum()),
            "valid": bool(finite.all())}


def _describe_model(path: Path) -> dict[str, Any]:
    from ..io.modelfile import read_header
    from .modelfile import load_model

    header = read_header(path)
    model = load_model(path)  # checks the weights: present, of the right shape and kind, finite
    out = {"kind": f"neumat model ({header.get('type', '?')})", **_on_disk(path),
           "neumat_version": header.get("neumat_version", "?"), "material": model.describe(),
           "parameters": sum(p.numel() for p in model.parameters())}
    bound = getattr(model, "output_bound_values", lambda: None)()  # a latent model's bound on its output
    if bound is not None:
        out["output_bound"] = ", ".join(f"{b:.4g}" for b in bound)
    source = header.get("source") or {}
    if source:
        out["source"] = source.get("name", "?")
    for key, value in (header.get("metrics") or {}).items():
        out[f"metric_{key}"] = value
    sampled = _sampled_range(model)  # a BRDF model's value range (finite: valid)
    return {**out, **sampled, "valid": sampled.get("valid", True)}


def _describe_btf(path: Path) -> dict[str, Any]:
    from ..io.btf import read_btf_table

    btf = read_btf_table(path)  # checks shapes, dtypes, directions and values
    n_l, n_v, h, w, _ = btf.data.shape
    return {"kind": "neumat BTF (.nbtf)", **_on_disk(path), "label": btf.label,
            "resolution": f"{w} x {h} texels, {n_l} light x {n_v} view directions, RGB",
            "value_min": float(btf.data.min()), "value_max": float(btf.data.max()), "valid": True}


def _describe_image(path: Path) -> dict[str, Any]:
    from ..io.images import read_image

    img = read_image(path)
    finite = np.isfinite(img)
    return {"kind": f"image ({path.suffix.lower()[1:]})", **_on_disk(path),
            "resolution": f"{img.shape[1]} x {img.shape[0]}, {img.shape[2]} channels",
            "value_min": float(img[finite].min()), "value_max": float(img[finite].max()),
            "non_finite_entries": int((~finite).sum()), "valid": bool(finite.all())}


def _sampled_range(material, n: int = 1 << 14) -> dict[str, Any]:
    """Value range of a BRDF over n cosine-distributed (wi, wo) pairs (fixed seed)."""
    from ..warp.hemisphere import sample_cosine_hemisphere

    if material.spatially_varying or material.full_sphere:
        return {}
    gen = torch.Generator().manual_seed(0)
    wi = sample_cosine_hemisphere(torch.rand(n, 2, generator=gen))
    wo = sample_cosine_hemisphere(torch.rand(n, 2, generator=gen))
    ok = (wi[:, 2] > 1e-4) & (wo[:, 2] > 1e-4)
    with torch.no_grad():
        f = material.eval(Query(wi[ok], wo[ok]))
    finite = torch.isfinite(f)
    return {"sampled_value_min": float(f[finite].min()), "sampled_value_max": float(f[finite].max()),
            "valid": bool(finite.all())}
