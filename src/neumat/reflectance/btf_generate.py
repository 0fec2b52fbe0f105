"""Generate a BTF from a PBR texture set by ray marching its displaced height field.

For every view direction the texels of the reference plane (z = mean height) are seen orthographically:
each (sub-)pixel ray arriving along -wo is marched to its first intersection with the height field
(parallax and masking). For every light direction the hit point is lit by a directional light of unit
irradiance perpendicular to it, with cast shadows (a second march towards wi), and shaded with the
principled BRDF of the texture maps at the hit point in the frame of the local surface normal. Direct light
only: inter-reflections between surface bumps are ignored. The lights of one elevation are shaded and
shadow-marched together (`elevation_groups`; the march takes the same steps as for each light alone).

Stored value: apparent BRDF = outgoing radiance / cos(theta_light) of the macro surface (cosine excluded,
like every neumat BRDF), see `neumat.reflectance.btf`.
"""
from __future__ import annotations

import math
from typing import Callable

import torch

from ..core.errors import InputError
from ..io.texture_set import TextureSet
from .btf import TabulatedBTF
from .heightfield import HeightField
from .microfacet import principled_eval

#: shader(wi_local (N, 3), wo_local (N, 3), color (N, 3), metalness (N,), roughness (N,)) -> BRDF (N, 3)
Shader = Callable[[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor], torch.Tensor]


def principled_shader(wi, wo, color, metalness, roughness) -> torch.Tensor:
    """The principled BRDF (isotropic, specular 0.5) of the texture maps."""
    return principled_eval(wi, wo, color, metalness, roughness, torch.zeros_like(roughness))


def lambert_shader(wi, wo, color, metalness, roughness) -> torch.Tensor:
    """color / pi above the surface (for validation and tests)."""
    up = ((wi[:, 2] > 0) & (wo[:, 2] > 0)).to(color.dtype)[:, None]
    return color / math.pi * up


def _frame(n: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Tangent and bitangent (N, 3) of unit normals n (N, 3), the tangent closest to +x."""
    x = torch.zeros_like(n)
    x[:, 0] = 1
    t = x - n * n[:, :1]
    t = t / t.norm(dim=-1, keepdim=True).clamp(min=1e-8)
    return t, torch.cross(n, t, dim=-1)


def generate_btf(textures: TextureSet, light_dirs: torch.Tensor, view_dirs: torch.Tensor,
                 relief: float | None = None, spp: int = 4, shadows: bool = True, normals: str = "height",
                 shader: Shader = principled_shader, step: float = 0.25, device=None, progress: bool = False,
                 label: str | None = None, noise: float = 0.0, noise_seed: int = 0) -> TabulatedBTF:
    """BTF (L, V, H, W, 3) of `textures` (H x W texels) seen from `view_dirs` under `light_dirs`.

    relief: displacement in texels of a height-map value of 1 (default: textures.height_scale * W, the
    set's own scale when the set is a whole texture). spp: sub-pixel rays per texel (a square number,
    stratified). shadows: cast shadows on (False gives the height field without light occlusion).
    normals: "height" (normals of the displaced height field) or "map" (the set's normal map).
    noise: relative std of measurement-like sensor noise (`sensor_noise`; 0: none), drawn with `noise_seed`.
    """
    if normals not in ("height", "map"):
        raise InputError(f"generate_btf normals: expected 'height' or 'map', got {normals!r}")
    if not noise >= 0:
        raise InputError(f"generate_btf noise: expected a relative std >= 0, got {noise}")
    root = int(round(math.sqrt(spp)))
    if spp < 1 or root * root != spp:
        raise InputError(f"generate_btf spp: expected a square number >= 1, got {spp}")
    for name, d in (("light", light_dirs), ("view", view_dirs)):
        if d.dim() != 2 or d.shape[1] != 3 or bool((d[:, 2] <= 0).any()):
            raise InputError(f"generate_btf {name}_dirs: expected (D, 3) upper-hemisphere directions")
    device = torch.device(device) if device is not None else textures.color.device
    tex = textures.to(device)
    h, w = tex.size
    relief = tex.height_scale * w if relief is None else float(relief)
    field = HeightField(tex.height * relief, step=step)
    shading_normals = field.normals() if normals == "height" else tex.normal
    maps = torch.cat([tex.color, tex.metalness[..., None], tex.roughness[..., None], shading_normals], -1)

    # stratified sub-pixel positions of every texel, (H * W * spp,)
    rows, cols = torch.meshgrid(torch.arange(h, device=device), torch.arange(w, device=device), indexing="ij")
    off = (torch.arange(root, device=device) + 0.5) / root
    oy, ox = torch.meshgrid(off, off, indexing="ij")
    s0 = (cols[..., None].float() + ox.reshape(-1)).reshape(-1)
    t0 = (h - rows[..., None].float() - oy.reshape(-1)).reshape(-1)

    ld = light_dirs.to(device, torch.float32)
    vd = view_dirs.to(device, torch.float32)
    out = torch.zeros(ld.shape[0], vd.shape[0], h, w, 3, device=device)
    light_groups = elevation_groups(ld, s0.shape[0])
    views = range(vd.shape[0])
    if progress:
        from rich.progress import track
        views = track(views, description=f"generating BTF {label or tex.name}")
    for v in views:
        wo = vd[v].expand(s0.shape[0], 3)
        p = field.intersect_view(s0, t0, wo)
        m = field.sample(maps, p[:, 0], p[:, 1])
        color, metal, rough = m[:, :3].clamp(0, 1), m[:, 3].clamp(0, 1), m[:, 4].clamp(0, 1)
        n = m[:, 5:8] / m[:, 5:8].norm(dim=-1, keepdim=True)
        tangent, bitangent = _frame(n)
        to_local = torch.stack([tangent, bitangent, n], 1)              # (N, 3, 3) rows = frame axes
        wo_local = (to_local @ wo[:, :, None])[..., 0]
        for group in light_groups:
            k = group.numel()
            wi = ld[group][:, None, :].expand(k, s0.shape[0], 3).reshape(-1, 3)     # (k N, 3), light-major
            wi_local = (to_local.repeat(k, 1, 1) @ wi[:, :, None])[..., 0]
            f = shader(wi_local, wo_local.repeat(k, 1), color.repeat(k, 1), metal.repeat(k), rough.repeat(k))
            radiance = f * wi_local[:, 2:3].clamp(min=0)
            if shadows:
                radiance = radiance * field.visible(p.repeat(k, 1), wi).to(radiance.dtype)[:, None]
            radiance = radiance.reshape(k, h * w, spp, 3).mean(2) / ld[group, 2][:, None, None]
            out[group, v] = radiance.reshape(k, h, w, 3)
    if noise > 0:
        out = sensor_noise(out, noise, noise_seed)
    return TabulatedBTF(out, ld, vd, label=label or tex.name)


def sensor_noise(data: torch.Tensor, relative: float, seed: int = 0) -> torch.Tensor:
    """`data` (any shape, >= 0) with independent Gaussian noise of std `relative` x value per entry, clamped at 0:
    the noise of an HDR-merged camera measurement, whose exposures keep each entry's noise about a fixed
    fraction of its value (the UBO2014 captures). Same seed, same noise."""
    g = torch.Generator(device=data.device).manual_seed(seed)
    return (data * (1 + relative * torch.randn(data.shape, generator=g, device=data.device))).clamp(min=0)


def elevation_groups(dirs: torch.Tensor, per_direction: int, max_points: int = 1 << 20) -> list[torch.Tensor]:
    """Indices of the directions `dirs` (D, 3) grouped by equal elevation (z within 1e-6), each group cut
    into chunks of at most max(1, max_points // per_direction) directions. A shadow march of a group takes
    the same steps as that of each of its directions alone: its step count depends on the elevation only."""
    z = dirs[:, 2]
    order = torch.argsort(z)
    cut = torch.nonzero(z[order].diff().abs() > 1e-6).flatten() + 1
    chunk = max(1, max_points // max(per_direction, 1))
    groups = []
    for ring in torch.tensor_split(order, cut.tolist()):
        groups.extend(ring.split(chunk))
    return groups


def texture_tile(textures: TextureSet, size: int, crop: int | None = None, row: int = 0, col: int = 0
                 ) -> tuple[TextureSet, float]:
    """A crop x crop texel tile of `textures` at (row, col), resampled (antialiased) to size x size, and its
    relief: the displacement in tile texels of a height value of 1 (from textures.height_scale)."""
    import torch.nn.functional as F
    from dataclasses import replace

    full_w = textures.size[1]
    crop = min(textures.size) if crop is None else crop
    tile = textures.crop(row, col, crop, crop)

    def resize(t: torch.Tensor) -> torch.Tensor:
        x = (t if t.dim() == 3 else t[..., None]).permute(2, 0, 1)[None]
        y = F.interpolate(x, size=(size, size), mode="bilinear", antialias=True, align_corners=False)[0]
        y = y.permute(1, 2, 0)
        return y if t.dim() == 3 else y[..., 0]

    normal = resize(tile.normal)
    tile = replace(tile, color=resize(tile.color), normal=normal / normal.norm(dim=-1, keepdim=True),
                   roughness=resize(tile.roughness), metalness=resize(tile.metalness), height=resize(tile.height))
    return tile, textures.height_scale * full_w * size / crop

