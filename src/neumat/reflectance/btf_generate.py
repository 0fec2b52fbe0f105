"""Generate a BTF from a PBR texture set by ray marching its displaced height field.

For every view direction the texels of the reference plane (z = mean height) are seen orthographically:
each (sub-)pixel ray arriving along -wo is marched to its first intersection with the height field
(parallax and masking). For every light direction the hit point is lit by a directional light of unit
irradiance perpendicular to it, with cast shadows (a second march towards wi), and shaded with the
principled BRDF of the texture maps at the hit point in the frame of the local surface normal. The lights of
one elevation are shaded and shadow-marched together (`elevation_groups`; the march takes the same steps as
for each light alone).

Details: docs/notes/reflectance.md, section `neumat.reflectance.btf_generate`.
"""
from __future__ import annotations

import math
from typing import Callable

import torch

from ..core.errors import InputError
from ..io.texture_set import TextureSet
from ..warp.hemisphere import sample_cosine_hemisphere
from .btf import TabulatedBTF
from .fibre_field import fibre_field, fibre_tangents
from .heightfield import HeightField
from .microfacet import principled_eval, principled_sample

#: shader(wi_local (N, 3), wo_local (N, 3), color (N, 3), metalness (N,), roughness (N,)) -> BRDF (N, 3)
Shader = Callable[[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor], torch.Tensor]


def principled_shader(wi, wo, color, metalness, roughness) -> torch.Tensor:
    """The principled BRDF (isotropic, specular 0.5) of the texture maps."""
    return principled_eval(wi, wo, color, metalness, roughness, torch.zeros_like(roughness))


def lambert_shader(wi, wo, color, metalness, roughness) -> torch.Tensor:
    """color / pi above the surface (for validation and tests)."""
    up = ((wi[:, 2] > 0) & (wo[:, 2] > 0)).to(color.dtype)[:, None]
    return color / math.pi * up


def fibre_shader(anisotropy: float) -> Shader:
    """The principled BRDF with its GGX lobe stretched along the local x axis (the fibre direction) by
    `anisotropy` in [0, 1] (Burley's aspect; 0: `principled_shader`)."""
    def shader(wi, wo, color, metalness, roughness) -> torch.Tensor:
        return principled_eval(wi, wo, color, metalness, roughness, torch.full_like(roughness, anisotropy))
    return shader


def _frame(n: torch.Tensor, x: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Tangent and bitangent (N, 3) of unit normals n (N, 3), the tangent closest to x (N, 3) (default +x)."""
    if x is None:
        x = torch.zeros_like(n)
        x[:, 0] = 1
    t = x - n * (n * x).sum(-1, keepdim=True)
    t = t / t.norm(dim=-1, keepdim=True).clamp(min=1e-8)
    return t, torch.cross(n, t, dim=-1)


def _surface(field: HeightField, maps: torch.Tensor, p: torch.Tensor, fibres: bool):
    """Material (color (N, 3), metalness (N,), roughness (N,)) and local frame (N, 3, 3) (rows: tangent,
    bitangent, normal) at surface points p (N, 3): bilinear lookups of `maps` (see generate_btf)."""
    m = field.sample(maps, p[:, 0], p[:, 1])
    n = m[:, 5:8] / m[:, 5:8].norm(dim=-1, keepdim=True)
    tangent, bitangent = _frame(n, fibre_tangents(m[:, 8:10]) if fibres else None)
    return (m[:, :3].clamp(0, 1), m[:, 3].clamp(0, 1), m[:, 4].clamp(0, 1)), torch.stack([tangent, bitangent, n], 1)


def _strata(n: int, samples: int, generator: torch.Generator, device) -> torch.Tensor:
    """Points (n samples, 2) of the unit square: `samples` (a square) strata, jittered independently per point."""
    root = int(round(math.sqrt(samples)))
    j, i = torch.meshgrid(torch.arange(root), torch.arange(root), indexing="ij")
    cells = torch.stack([i.reshape(-1), j.reshape(-1)], -1).float()
    u = (cells + torch.rand(n, samples, 2, generator=generator)) / root
    return u.reshape(-1, 2).clamp(0, 1 - 1e-7).to(device)


def generate_btf(textures: TextureSet, light_dirs: torch.Tensor, view_dirs: torch.Tensor,
                 relief: float | None = None, spp: int = 4, shadows: bool = True, normals: str = "height",
                 shader: Shader = principled_shader, step: float = 0.25, device=None, progress: bool = False,
                 label: str | None = None, noise: float = 0.0, noise_seed: int = 0, interreflection: int = 0,
                 interreflection_seed: int = 0, fibres: float = 0.0, fibre_direction: str = "grain"
                 ) -> TabulatedBTF:
    """BTF (L, V, H, W, 3) of `textures` (H x W texels) seen from `view_dirs` under `light_dirs`.

    relief: displacement in texels of a height-map value of 1 (default: textures.height_scale * W, the
    set's own scale when the set is a whole texture). spp: sub-pixel rays per texel (a square number,
    stratified). shadows: cast shadows on (False gives the height field without light occlusion).
    normals: "height" (normals of the displaced height field) or "map" (the set's normal map).
    noise: relative std of measurement-like sensor noise (`sensor_noise`; 0: none), drawn with `noise_seed`.
    interreflection: hemisphere directions per ray hit (a square number) for one bounce of inter-reflection
    (0: direct light only; drawn from the BRDF with the principled shader, cosine-weighted with any other),
    jittered with `interreflection_seed`; at most about (1 + interreflection) x the
    direct-only time (7x measured at 16 on a 50 x 50 real-set crop: most bounce rays escape).
    fibres: anisotropy in [0, 1] of the principled shader's GGX lobe along the fibre field `fibre_direction`
    of the displaced height map (`fibre_field` kinds: "grain", "weave:<p>", "angle:<deg>"); 0: isotropic.
    """
    if normals not in ("height", "map"):
        raise InputError(f"generate_btf normals: expected 'height' or 'map', got {normals!r}")
    if not noise >= 0:
        raise InputError(f"generate_btf noise: expected a relative std >= 0, got {noise}")
    root = int(round(math.sqrt(spp)))
    if spp < 1 or root * root != spp:
        raise InputError(f"generate_btf spp: expected a square number >= 1, got {spp}")
    bounce_root = int(round(math.sqrt(interreflection)))
    if interreflection < 0 or bounce_root * bounce_root != interreflection:
        raise InputError(f"generate_btf interreflection: expected 0 or a square number of directions, got "
                         f"{interreflection}")
    if not 0 <= fibres <= 1:
        raise InputError(f"generate_btf fibres: expected an anisotropy in [0, 1], got {fibres}")
    principled = shader is principled_shader                    # the bounce then samples the BRDF
    if fibres > 0:
        if shader is not principled_shader:
            raise InputError("generate_btf fibres: the fibre lobe is the principled shader's; got another shader")
        shader = fibre_shader(fibres)
    for name, d in (("light", light_dirs), ("view", view_dirs)):
        if d.dim() != 2 or d.shape[1] != 3 or bool((d[:, 2] <= 0).any()):
            raise InputError(f"generate_btf {name}_dirs: expected (D, 3) upper-hemisphere directions")
    device = torch.device(device) if device is not None else textures.color.device
    tex = textures.to(device)
    h, w = tex.size
    relief = tex.height_scale * w if relief is None else float(relief)
    field = HeightField(tex.height * relief, step=step)
    shading_normals = field.normals() if normals == "height" else tex.normal
    maps = [tex.color, tex.metalness[..., None], tex.roughness[..., None], shading_normals]
    if fibres > 0:
        maps.append(fibre_field(tex.height.cpu(), fibre_direction).to(device))
    maps = torch.cat(maps, -1)

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
    generator = torch.Generator().manual_seed(interreflection_seed)
    views = range(vd.shape[0])
    if progress:
        from rich.progress import track
        views = track(views, description=f"generating BTF {label or tex.name}")
    for v in views:
        wo = vd[v].expand(s0.shape[0], 3)
        p = field.intersect_view(s0, t0, wo)
        (color, metal, rough), to_local = _surface(field, maps, p, fibres > 0)
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
        if interreflection:
            bounce = _one_bounce(field, maps, shader, ld, p, to_local, wo_local, (color, metal, rough),
                                 interreflection, shadows, fibres, generator, principled)   # (L, N, 3)
            out[:, v] += (bounce.reshape(-1, h * w, spp, 3).mean(2) / ld[:, 2, None, None]).reshape(-1, h, w, 3)
    if noise > 0:
        out = sensor_noise(out, noise, noise_seed)
    return TabulatedBTF(out, ld, vd, label=label or tex.name)


def _one_bounce(field, maps, shader, ld, p, to_local, wo_local, material, samples, shadows, fibres, generator,
                principled) -> torch.Tensor:
    """Radiance (L, N, 3) reflected towards wo at the hits p (N, 3) of light that reached them from the directly
    lit (and, with `shadows`, shadowed) height-field points seen along `samples` stratified directions of each
    hit's hemisphere. Directions: with the principled shader (`principled`, anisotropy `fibres`) drawn from its
    BRDF (`principled_sample`: cosine and GGX lobes, so glossy hits do not make fireflies), else cosine-weighted;
    estimate: mean of BRDF x cos x incoming radiance / pdf."""
    n = p.shape[0]
    color, metal, rough = (x.repeat_interleave(samples, 0) for x in material)
    u = _strata(n, samples, generator, p.device)                                  # (N S, 2), point-major
    wo = wo_local.repeat_interleave(samples, 0)
    if principled:
        d_local, pdf = principled_sample(wo, u, color, metal, rough, torch.full_like(rough, fibres))
        cos = d_local[:, 2:3].clamp(min=0)
        ok = (pdf > 0) & (d_local[:, 2] > 0)
        weight = torch.where(ok[:, None], shader(d_local, wo, color, metal, rough) * cos
                             / pdf.clamp(min=1e-12)[:, None], torch.zeros_like(color))
        d_local = torch.where(ok[:, None], d_local, torch.tensor([0.0, 0.0, 1.0], device=p.device))
    else:
        d_local = sample_cosine_hemisphere(u)
        weight = shader(d_local, wo, color, metal, rough) * math.pi
    weight = weight / samples
    d = (to_local.repeat_interleave(samples, 0).transpose(1, 2) @ d_local[:, :, None])[..., 0]
    q, hit = field.trace(p.repeat_interleave(samples, 0), d)
    out = torch.zeros(ld.shape[0], n, 3, device=p.device)
    idx = torch.nonzero(hit & (weight.amax(-1) > 0)).flatten()
    if idx.numel() == 0:
        return out
    q, d, weight, owner = q[idx], d[idx], weight[idx], idx // samples
    (color_q, metal_q, rough_q), to_local_q = _surface(field, maps, q, fibres > 0)
    wo_q = (to_local_q @ -d[:, :, None])[..., 0]
    for group in elevation_groups(ld, idx.numel()):
        k = group.numel()
        wi = ld[group][:, None, :].expand(k, idx.numel(), 3).reshape(-1, 3)
        wi_q = (to_local_q.repeat(k, 1, 1) @ wi[:, :, None])[..., 0]
        radiance = shader(wi_q, wo_q.repeat(k, 1), color_q.repeat(k, 1), metal_q.repeat(k), rough_q.repeat(k))
        radiance = radiance * wi_q[:, 2:3].clamp(min=0)
        if shadows:
            radiance = radiance * field.visible(q.repeat(k, 1), wi).to(radiance.dtype)[:, None]
        contribution = (radiance * weight.repeat(k, 1)).reshape(k, -1, 3)
        out[group] = torch.zeros(k, n, 3, device=p.device).index_add_(1, owner, contribution)
    return out


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

