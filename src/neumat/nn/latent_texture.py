"""Textures over uv with wrap tiling: bilinear lookup, mip pyramids and differentiable anisotropic filtering.

Texture layout: (C, H, W) tensors in image orientation, as `neumat.io.texture_set`: texel (row i, column j)
has its centre at uv = ((j + 0.5) / W, 1 - (i + 0.5) / H); u points right, v up; lookups wrap (tile).

Details: src/neumat/methods/latent_mlp/NOTES.md, section `neumat.nn.latent_texture`.
"""
from __future__ import annotations

import functools
import math

import torch
import torch.nn.functional as F
from torch import nn

from ..core.checks import check_finite, check_int, check_shape
from ..core.errors import InputError
from ..core.tensors import derived_from, module_stamp
from .preconditioner import FrequencyPreconditioner, flat_levels


def texel_coords(uv: torch.Tensor, height: int, width: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Continuous texel coordinates (x, y), each (N,), of uv (N, 2): x = u W - 1/2, y = (1 - v) H - 1/2."""
    return uv[:, 0] * width - 0.5, (1 - uv[:, 1]) * height - 0.5


def bilinear(tex: torch.Tensor, uv: torch.Tensor) -> torch.Tensor:
    """Bilinear lookup with wrap tiling: tex (C, H, W), uv (N, 2) -> (N, C); differentiable in tex.
    One fused `grid_sample` over the texture padded circularly by one texel (corner-aligned grid)."""
    return bilinear_padded(wrap_padded(tex), uv)


def wrap_padded(tex: torch.Tensor) -> torch.Tensor:
    """tex (C, H, W) padded circularly by one texel, (1, C, H + 2, W + 2): what `bilinear_padded` reads (a copy
    of the whole texture, so a caller that looks up the same texture often keeps it)."""
    return F.pad(tex.unsqueeze(0), (1, 1, 1, 1), mode="circular")


def bilinear_maps(owner: object, maps: torch.Tensor, uv: torch.Tensor) -> torch.Tensor:
    """`bilinear` of fixed data maps (C, H, W) (a source's PBR maps) at uv (N, 2), in uv's dtype and device, read
    from `padded_maps`. Why: a source's lookups otherwise pad its whole texture on every call and miss the cache once
    per channel (a 1K set: 47 ms per 65k lookups, 7 ms kept); same values as `bilinear`."""
    return bilinear_padded(padded_maps(owner, maps, uv.dtype, uv.device), uv)


def padded_maps(owner: object, maps: torch.Tensor, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    """`wrap_padded` of fixed data maps (C, H, W) in dtype on device, (1, C, H + 2, W + 2) in channels-last order
    (a lookup reads a texel's channels together), made once per dtype and device and kept on `owner`
    (`derived_from`; made every call when maps needs a gradient)."""
    return derived_from(owner, f"padded maps {maps.data_ptr()} {dtype} {device}", [maps], lambda: wrap_padded(
        maps.to(device, dtype)).contiguous(memory_format=torch.channels_last), optimised=False)


def bilinear_padded(padded: torch.Tensor, uv: torch.Tensor) -> torch.Tensor:
    """`bilinear` of the texture that `wrap_padded` padded: (N, C)."""
    c, h, w = padded.shape[1], padded.shape[2] - 2, padded.shape[3] - 2
    x, y = texel_coords(torch.remainder(uv.to(padded.dtype), 1.0), h, w)  # in [-1/2, W - 1/2], [-1/2, H - 1/2]
    grid = torch.stack([(x + 1) * (2 / (w + 1)) - 1, (y + 1) * (2 / (h + 1)) - 1], -1)
    out = F.grid_sample(padded, grid.view(1, 1, -1, 2), mode="bilinear", padding_mode="border", align_corners=True)
    return out.view(c, -1).t().contiguous()  # row-major: per-row reductions (e.g. norms) of slices stay fast


def _kept_channels_last(tex: torch.Tensor) -> torch.Tensor:
    """A derived texture (1, C, H, W) as `derived_from` keeps it: without autograd in channels-last order, so that a
    lookup reads each texel's channels from one cache line (`bilinear_maps`; the same values), else as it is."""
    return tex if torch.is_grad_enabled() else tex.contiguous(memory_format=torch.channels_last)


def box_pyramid(tex: torch.Tensor) -> list[torch.Tensor]:
    """Mip levels of tex (C, H, W) down to 1 x 1 by 2 x 2 box averaging (odd sizes: the last texel row /
    column is averaged in with the area-weighted resize). Level 0 is `tex` itself."""
    levels = [tex]
    while max(levels[-1].shape[1:]) > 1:
        c, h, w = levels[-1].shape
        size = (max(1, h // 2), max(1, w // 2))
        levels.append(F.adaptive_avg_pool2d(levels[-1].unsqueeze(0), size)[0])
    return levels


def pyramid_levels(height: int, width: int) -> int:
    """Number of levels of a full pyramid of a height x width texture (down to 1 x 1)."""
    return 1 + int(math.floor(math.log2(max(height, width))))


def check_footprint(footprint: torch.Tensor, name: str = "footprint") -> torch.Tensor:
    """Check (N, 2, 2) symmetric positive definite covariances; raise InputError naming the first bad one."""
    check_shape(footprint, name, (-1, 2, 2))
    check_finite(footprint, name)
    if footprint.shape[0] == 0:
        return footprint
    a, b, b2, c = footprint[:, 0, 0], footprint[:, 0, 1], footprint[:, 1, 0], footprint[:, 1, 1]
    scale = footprint.abs().amax(dim=(1, 2)).clamp(min=1e-30)
    asym = (b - b2).abs() > 1e-5 * scale
    if bool(asym.any()):
        i = int(asym.nonzero()[0])
        raise InputError(f"{name}[{i}]: expected a symmetric matrix, got {footprint[i].tolist()}")
    det = a * c - b * b
    bad = (a <= 0) | (c <= 0) | (det <= 0)
    if bool(bad.any()):
        i = int(bad.nonzero()[0])
        raise InputError(f"{name}[{i}]: expected a positive definite covariance (positive diagonal and "
                         f"determinant), got {footprint[i].tolist()} with determinant {float(det[i]):.3g}")
    return footprint


def footprint_axes(cov: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Standard deviations along the major and minor axes (N,) and the unit major direction (N, 2) of
    covariances cov (N, 2, 2)."""
    a, b, c = cov[:, 0, 0], cov[:, 0, 1], cov[:, 1, 1]
    mean, half = (a + c) / 2, torch.sqrt(((a - c) / 2) ** 2 + b * b)
    theta = 0.5 * torch.atan2(2 * b, a - c)
    major = (mean + half).clamp(min=0).sqrt()
    minor = (mean - half).clamp(min=0).sqrt()
    return major, minor, torch.stack([torch.cos(theta), torch.sin(theta)], -1)


@functools.lru_cache(maxsize=64)
def atlas_layout(sizes: tuple[tuple[int, int], ...], device: torch.device) -> dict[str, torch.Tensor]:
    """Layout of an atlas of levels of sizes ((H_l, W_l), ...), each padded circularly by one texel: level 0
    on the left, the others stacked top to bottom to its right. Returns "source" (H_a W_a,) (long: the
    `flat_levels` column of every atlas texel, 0 for unused ones), "size" (L, 2) (W_l, H_l), "origin" (L, 2)
    (float64 atlas coordinates (x, y) of texel coordinate (0, 0) of each level) and "shape" (2,) (W_a, H_a)."""
    places, top = [(0, 0)], 0  # (left, top) of every padded level
    for h, _ in sizes[1:]:
        places.append((sizes[0][1] + 2, top))
        top += h + 2
    height = max(sizes[0][0] + 2, top)
    width = sizes[0][1] + 2 + (max(w for _, w in sizes[1:]) + 2 if len(sizes) > 1 else 0)
    source = torch.zeros(height, width, dtype=torch.long)
    start = 0
    for (h, w), (left, top) in zip(sizes, places):
        rows = torch.remainder(torch.arange(-1, h + 1), h)
        cols = torch.remainder(torch.arange(-1, w + 1), w)
        source[top:top + h + 2, left:left + w + 2] = start + rows[:, None] * w + cols[None, :]
        start += h * w
    return {"source": source.flatten().to(device), "size": torch.tensor([(w, h) for h, w in sizes], device=device),
            "origin": torch.tensor([(left + 1, top + 1) for left, top in places], dtype=torch.float64, device=device),
            "shape": torch.tensor([width, height], device=device)}


class _Atlas(torch.autograd.Function):
    """levels -> atlas (C, H_a, W_a): each level padded circularly by one texel and copied to (left, top) of its
    padded block, in the store's earlier atlas when its shape, dtype and device match (a training step then
    allocates and zeroes no 1K-sized atlas: about 50 MB, most of it page faults); the backward pass reads each
    level's block and folds the padding back onto the texels it copies (no full-atlas gradient copies per level,
    as autograd's slice assignment would make)."""

    @staticmethod
    def forward(ctx, places, height, width, store, *levels):
        ctx.places = places
        shape = (levels[0].shape[0], height, width)
        buffer = store[0] if store else None
        reuse = buffer is not None and buffer.shape == shape and buffer.dtype == levels[0].dtype \
            and buffer.device == levels[0].device
        atlas = buffer if reuse else levels[0].new_zeros(shape)  # the blocks below overwrite what they cover
        for tex, (left, top) in zip(levels, places):
            h, w = tex.shape[1:]
            block = atlas[:, top:top + h + 2, left:left + w + 2]
            block[:, 1:h + 1, 1:w + 1] = tex
            block[:, 0, 1:w + 1], block[:, h + 1, 1:w + 1] = tex[:, -1], tex[:, 0]
            block[:, :, 0], block[:, :, w + 1] = block[:, :, w], block[:, :, 1]
        ctx.shapes = [tex.shape for tex in levels]
        store[:] = [atlas]
        return atlas.view_as(atlas)  # a view: the store itself keeps no autograd history

    @staticmethod
    def backward(ctx, grad):
        out = []
        for shape, (left, top) in zip(ctx.shapes, ctx.places):
            h, w = shape[1:]
            block = grad[:, top:top + h + 2, left:left + w + 2]
            g = block[:, 1:h + 1, 1:w + 1].clone()
            g[:, :, w - 1] += block[:, 1:h + 1, 0]  # the padding columns, rows and corners onto their texels
            g[:, :, 0] += block[:, 1:h + 1, w + 1]
            g[:, h - 1] += block[:, 0, 1:w + 1]
            g[:, 0] += block[:, h + 1, 1:w + 1]
            g[:, h - 1, w - 1] += block[:, 0, 0]
            g[:, h - 1, 0] += block[:, 0, w + 1]
            g[:, 0, w - 1] += block[:, h + 1, 0]
            g[:, 0, 0] += block[:, h + 1, w + 1]
            out.append(g)
        return (None, None, None, None, *out)


def build_atlas(levels: list[torch.Tensor], store: list | None = None) -> torch.Tensor:
    """The atlas (1, C, H_a, W_a) of `atlas_layout` of levels [(C, H_l, W_l)]: each level padded circularly by
    one texel and copied into its place (unused texels 0; they are never read). The same texels as
    `trilinear_flat`'s gather from `flat_levels`, with contiguous copies (and a folding backward) instead.
    store: a list holding the tensor that an earlier call wrote (reused when the shapes match, then replaced),
    or None for a new atlas; the earlier atlas's values are then overwritten (an autograd graph that still
    needs them fails at its backward, loudly, as after any in-place change)."""
    sizes = tuple(tuple(int(v) for v in tex.shape[1:]) for tex in levels)
    layout = atlas_layout(sizes, levels[0].device)
    width, height = (int(v) for v in layout["shape"])
    places = [(left - 1, top - 1) for left, top in layout["origin"].long().tolist()]
    return _Atlas.apply(places, height, width, [] if store is None else store, *levels).unsqueeze(0)


def trilinear_flat(flat: torch.Tensor | None, sizes: list[tuple[int, int]], uv: torch.Tensor, lod: torch.Tensor,
                   scale: torch.Tensor | None = None, level_u: torch.Tensor | None = None,
                   atlas: torch.Tensor | None = None) -> torch.Tensor:
    """Trilinear lookups (N, C) in the levels of sizes [(H_l, W_l)] stored as `flat_levels` (C, T): bilinear
    (wrap tiling) in the two levels around lod (N,) (clamped to the pyramid), blended linearly and multiplied
    by scale (N,) if given. With level_u (N,) uniform in [0, 1], one of the two levels instead, the finer unless
    level_u < the fractional part of lod (Russian roulette, Zeltner et al. 2024 Sec. 4.1). One `grid_sample`
    over an atlas of the circularly padded levels (`atlas`: `build_atlas` of the levels, when the caller has it;
    flat may then be None)."""
    layout = atlas_layout(tuple(tuple(int(v) for v in hw) for hw in sizes), uv.device)
    width, height = (int(v) for v in layout["shape"])
    if atlas is None:
        atlas = flat.index_select(1, layout["source"]).view(1, -1, height, width)
    flat = atlas  # dtype of the lookups
    lod = lod.clamp(0, len(sizes) - 1)
    lo = lod.floor()
    t = (lod - lo).to(flat.dtype)
    lo = lo.long()
    pair = torch.stack([lo, (lo + 1).clamp(max=len(sizes) - 1)], -1)  # (N, 2); weight t = 0 when clamped
    uv = torch.remainder(uv.to(flat.dtype), 1.0)
    flip = torch.stack([uv[:, 0], 1 - uv[:, 1]], -1).unsqueeze(1)  # (u, 1 - v)
    texel = flip * layout["size"][pair].to(flat.dtype) - 0.5  # (N, 2, 2): x = u W - 1/2, y = (1 - v) H - 1/2
    grid = (texel + layout["origin"][pair].to(flat.dtype)) * (2 / (layout["shape"].to(flat.dtype) - 1)) - 1
    # grid rows: the lower and the upper level of every lookup (CPU kernels vectorise along a grid row)
    out = F.grid_sample(atlas, grid.transpose(0, 1).unsqueeze(0), mode="bilinear", padding_mode="border",
                        align_corners=True)[0]  # (C, 2, N)
    if level_u is not None:
        t = (level_u.to(t.device) < t).to(flat.dtype)
    blend = torch.stack([1 - t, t])
    if scale is not None:
        blend = blend * scale.to(flat.dtype)
    return (out * blend).sum(1).t()


def trilinear(levels: list[torch.Tensor], uv: torch.Tensor, lod: torch.Tensor) -> torch.Tensor:
    """Trilinear lookup: bilinear in the two levels around lod (N,) (clamped to the pyramid), blended."""
    return trilinear_flat(flat_levels(levels), [tex.shape[1:] for tex in levels], uv, lod.to(uv.dtype))


def _probe_geometry(footprint: torch.Tensor, height: int, width: int, max_probes: int):
    """Per query (N,): probe count n, per-probe standard deviation sigma (level-0 texels), its lod, the major
    axis length and direction (N, 2) of footprints (N, 2, 2) on a height x width finest level."""
    scale = torch.tensor([width, height], dtype=footprint.dtype, device=footprint.device)
    cov_t = footprint * scale.view(1, 2, 1) * scale.view(1, 1, 2)  # in level-0 texels^2
    major, minor, axis = footprint_axes(cov_t)
    minor = minor.clamp(min=1e-12)
    n = torch.ceil(major / minor).clamp(1, max_probes)
    sigma = torch.maximum(minor, major / max_probes)  # per-probe standard deviation (texels)
    return n, sigma, torch.log2((2 * sigma).clamp(min=1e-12)), major, axis, scale


def footprint_lod(footprint: torch.Tensor, height: int, width: int, max_probes: int = 16) -> torch.Tensor:
    """The (unclamped) mip level (N,) whose trilinear probes `filter_anisotropic` uses for footprints (N, 2, 2)."""
    return _probe_geometry(footprint, height, width, max_probes)[2]


def filter_anisotropic(levels: list[torch.Tensor], uv: torch.Tensor, footprint: torch.Tensor,
                       max_probes: int = 16, flat: torch.Tensor | None = None,
                       level_u: torch.Tensor | None = None, atlas: torch.Tensor | None = None) -> torch.Tensor:
    """Gaussian-footprint filtered lookup of a pyramid (see src/neumat/methods/latent_mlp/NOTES.md).

    levels: mip levels (C, H_l, W_l), level 0 finest, level l about 2^l times coarser; uv (N, 2);
    footprint (N, 2, 2) covariance in uv^2. Returns (N, C), differentiable in the levels. `flat`: the
    levels' `flat_levels`, or `atlas` their `build_atlas`, when the caller has it already (levels then only give
    the sizes). level_u (N,): the probes of a query read one level by Russian roulette (`trilinear_flat`).
    """
    _, h, w = levels[0].shape
    n, sigma, lod, major, axis, scale = _probe_geometry(footprint, h, w, max_probes)
    spacing = torch.sqrt((12 * (major ** 2 - sigma ** 2)).clamp(min=0) / (n * n - 1).clamp(min=1))
    k = torch.arange(max_probes, device=uv.device, dtype=uv.dtype)
    offset = (k.unsqueeze(0) - (n.unsqueeze(-1) - 1) / 2) * spacing.unsqueeze(-1)  # (N, P) texels along axis
    used = k.unsqueeze(0) < n.unsqueeze(-1)
    delta = offset.unsqueeze(-1) * axis.unsqueeze(1) / scale  # (N, P, 2) uv offsets
    rows, probe = used.nonzero(as_tuple=True)
    if flat is None and atlas is None:
        flat = flat_levels(levels)
    values = trilinear_flat(flat, [tex.shape[1:] for tex in levels], uv[rows] + delta[rows, probe], lod[rows],
                            1 / n[rows], None if level_u is None else level_u[rows], atlas=atlas)
    return uv.new_zeros(uv.shape[0], values.shape[1], dtype=values.dtype).index_add(0, rows, values)


def isotropic_footprint(lod: torch.Tensor, width: int) -> torch.Tensor:
    """The covariance (N, 2, 2) in uv^2 that `filter_anisotropic` maps to mip level lod (N,) of a texture
    `width` texels wide: standard deviation 2^lod / 2 texels."""
    s = torch.exp2(lod) / (2 * width)
    eye = torch.eye(2, dtype=lod.dtype, device=lod.device)
    return (s * s).view(-1, 1, 1) * eye


class LatentPyramid(nn.Module):
    """A learned mip pyramid of latent vectors, every level its own parameter (C, size >> l, size >> l).

    forward(uv (N, 2), footprint (N, 2, 2) or None, lod (N,) or None) -> (N, C): anisotropic filtering
    with a footprint, trilinear with a lod only, bilinear at the finest level with neither. An optional
    `precondition` module (e.g. `neumat.nn.preconditioner.FrequencyPreconditioner`) maps each raw level
    parameter to the texture used in the forward pass.
    """

    def __init__(self, channels: int, size: int, init_std: float = 0.1, max_probes: int = 16,
                 precondition: nn.Module | None = None) -> None:
        super().__init__()
        if isinstance(size, bool) or not isinstance(size, int) or size < 1 or size & (size - 1):
            raise InputError(f"LatentPyramid.size: expected a power of two, got {size!r}")
        check_int(channels, "LatentPyramid.channels")
        self.size, self.channels, self.max_probes = size, channels, max_probes
        self.raw = nn.ParameterList(nn.Parameter(torch.randn(channels, size >> l, size >> l) * init_std)
                                    for l in range(pyramid_levels(size, size)))
        self.precondition = precondition

    def levels(self) -> list[torch.Tensor]:
        """The textures of the forward pass, finest first."""
        if self.precondition is None:
            return list(self.raw)
        return [self.precondition(t) for t in self.raw]

    def flat(self) -> torch.Tensor:
        """`flat_levels` (C, T) of `levels()` (all preconditioned at once when the preconditioner can)."""
        if isinstance(self.precondition, FrequencyPreconditioner):
            return self.precondition.flat(list(self.raw))
        return flat_levels(self.levels())

    def atlas(self) -> torch.Tensor:
        """`build_atlas` of `levels()` (all preconditioned at once when the preconditioner can): what the
        filtered and trilinear lookups read; built once while the levels are unchanged and no gradient is
        wanted (`derived_from`)."""
        return derived_from(self, "atlas", list(self.raw), lambda: _kept_channels_last(self._build_atlas()))

    def __getstate__(self) -> dict:
        state = super().__getstate__()
        return {k: v for k, v in state.items() if k not in ("_atlas_store", "_atlas_stamp")}  # copies need none

    def _build_atlas(self) -> torch.Tensor:
        # the first atlas of a training step (an optimiser stepped or a level changed since the last one) is written
        # into the last step's (`build_atlas`'s store), whose graph is gone; more lookups in the same step get their
        # own, as does an atlas without autograd (`derived_from` keeps it)
        store = None
        if torch.is_grad_enabled():
            stamp = module_stamp(self)
            if self.__dict__.get("_atlas_stamp") != stamp:
                store, self.__dict__["_atlas_stamp"] = self.__dict__.setdefault("_atlas_store", []), stamp
        if isinstance(self.precondition, FrequencyPreconditioner):
            return build_atlas(self.precondition.many(list(self.raw)), store)
        return build_atlas(self.levels(), store)

    def forward(self, uv: torch.Tensor, footprint: torch.Tensor | None = None,
                lod: torch.Tensor | None = None, level_u: torch.Tensor | None = None) -> torch.Tensor:
        if footprint is not None:
            return filter_anisotropic(list(self.raw), uv, footprint, self.max_probes, atlas=self.atlas(),
                                      level_u=level_u)
        if lod is not None:
            return trilinear_flat(None, [t.shape[1:] for t in self.raw], uv, lod.to(uv.dtype),
                                  level_u=level_u, atlas=self.atlas())
        return bilinear_padded(self.finest_padded(), uv)

    def finest_padded(self) -> torch.Tensor:
        """The finest level, preconditioned and `wrap_padded` (1, C, H + 2, W + 2): what a lookup without footprint
        or lod reads; kept while unchanged and no gradient is wanted (`derived_from`, channels-last)."""
        return derived_from(self, "finest", [self.raw[0]], lambda: _kept_channels_last(wrap_padded(
            self.raw[0] if self.precondition is None else self.precondition(self.raw[0]))))

    def level_fraction(self, footprint: torch.Tensor | None, lod: torch.Tensor | None, n: int,
                       device=None) -> torch.Tensor:
        """Weight t (N,) of the coarser of the two levels a footprint or lod reads (0 at the finest level only):
        the fractional part of the lod clamped to the pyramid."""
        if footprint is not None:
            lod = footprint_lod(footprint, self.size, self.size, self.max_probes)
        if lod is None:
            return torch.zeros(n, device=device)
        lod = lod.clamp(0, len(self.raw) - 1)
        return lod - lod.floor()

    def num_parameters(self) -> int:
        return sum(p.numel() for p in self.raw)
