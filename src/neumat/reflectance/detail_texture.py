"""Procedural SVBRDF texture sets with strong normal-map and roughness detail at every scale: the filtered
appearance the multi-scale paper selects its materials for (Timonen et al. 2025 choose MatSynth sets whose
filtered look is not a simple average of albedos), made with the package's own code so that a benchmark is
not limited to the few shared sets.

Kinds: "scratches", "brushed", "foil", "chainmail"; and "polished" (POLISHED_KINDS), a near-mirror metal without
roughness detail: the regime where the latent-texture fits used to blow up (issue 55).

Details: docs/notes/reflectance.md, section `neumat.reflectance.detail_texture`.
"""
from __future__ import annotations

import math

import torch

from ..core.checks import check_int
from ..core.errors import InputError
from ..io.texture_set import TextureSet, normals_from_height

DETAIL_KINDS = ("scratches", "brushed", "foil", "chainmail")
#: near-mirror sets: gentle relief, one low roughness everywhere (no roughness detail, so not among DETAIL_KINDS)
POLISHED_KINDS = ("polished",)
#: roughness of "polished" (alpha = 0.09^2 = 0.008, as the polished metal of issue 55)
POLISHED_ROUGHNESS = 0.09


def _grid(size: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Texel-centre coordinates (x, y) in [0, 1), each (size, size), y down the rows."""
    c = (torch.arange(size, dtype=torch.float32) + 0.5) / size
    y, x = torch.meshgrid(c, c, indexing="ij")
    return x, y


def _wrap(d: torch.Tensor) -> torch.Tensor:
    """Periodic difference in [-0.5, 0.5)."""
    return (d + 0.5) % 1 - 0.5


def _smooth_noise(size: int, cells: tuple[int, int], g: torch.Generator) -> torch.Tensor:
    """Tileable value noise (size, size) in [0, 1]: a random (rows, cols) lattice, bicubically upsampled with
    wrap-around."""
    rows, cols = cells
    lattice = torch.rand(1, 1, rows, cols, generator=g)
    padded = torch.nn.functional.pad(lattice, (2, 2, 2, 2), mode="circular")
    up = torch.nn.functional.interpolate(padded, scale_factor=(size / rows, size / cols), mode="bicubic",
                                         align_corners=False)
    oy, ox = round(2 * size / rows), round(2 * size / cols)
    out = up[0, 0, oy:oy + size, ox:ox + size]
    return (out - out.min()) / (out.max() - out.min()).clamp(min=1e-8)


# Each maker returns (colour (S, S, 3) linear RGB, z (S, S) displacement in texture widths, roughness (S, S),
# metalness (S, S)). Features drawn in texels (scratch and streak widths) get depths in proportion to their
# width, features drawn in uv (foil creases, rings) fixed depths, so that slopes, and so normal tilts, do not
# depend on the size.

def _scratches(size, g, x, y):
    z = 0.002 * _smooth_noise(size, (8, 8), g)
    rough = 0.12 + 0.05 * _smooth_noise(size, (16, 16), g)
    for _ in range(max(40, size)):  # a few hundred at 256^2
        c, angle = torch.rand(2, generator=g), math.pi * float(torch.rand((), generator=g))
        length = 0.05 + 0.35 * float(torch.rand((), generator=g))
        width = (0.6 + 1.0 * float(torch.rand((), generator=g))) / size           # uv
        depth = (0.3 + 0.6 * float(torch.rand((), generator=g))) * width          # slopes 0.35-1.0
        dx, dy = _wrap(x - c[0]), _wrap(y - c[1])
        along = dx * math.cos(angle) + dy * math.sin(angle)
        across = -dx * math.sin(angle) + dy * math.cos(angle)
        groove = torch.exp(-(across / width) ** 2) * (along.abs() < length / 2)
        z = z - depth * groove
        rough = torch.maximum(rough, 0.45 * groove)
    return torch.tensor([0.78, 0.78, 0.8]).expand(size, size, 3), z, rough, torch.ones(size, size)


def _brushed(size, g, x, y):
    across = _smooth_noise(size, (size, 4), g)              # one value per texel row, slow along u
    fine = _smooth_noise(size, (max(size // 2, 4), 2), g)
    z = (0.6 * across + 0.3 * fine) / size                  # tilts across the brushing of a few degrees
    rough = 0.15 + 0.35 * _smooth_noise(size, (max(size // 4, 4), 2), g)
    return torch.tensor([0.91, 0.92, 0.92]).expand(size, size, 3), z, rough, torch.ones(size, size)


def _foil(size, g, x, y):
    z = torch.zeros(size, size)
    rough = torch.full((size, size), 0.08)
    for cells, amplitude in ((6, 0.08), (12, 0.04), (24, 0.02)):  # ridged noise: creases and facets
        n = _smooth_noise(size, (cells, cells), g) - 0.5
        z = z - amplitude * n.abs()
        rough = rough + 0.1 * torch.exp(-(n / 0.03) ** 2)  # rougher along the creases
    return torch.tensor([0.95, 0.78, 0.38]).expand(size, size, 3), z, rough, torch.ones(size, size)


def _chainmail(size, g, x, y):
    rings = 8                                               # rings a side
    r_ring, r_wire = 0.36 / rings, 0.11 / rings             # uv
    wire = torch.zeros(size, size)
    for o in range(2):                                      # staggered lattice: two offset sub-lattices
        c = (torch.arange(rings) + 0.25 + 0.5 * o) / rings
        dx = _wrap(x[None, None] - c[None, :, None, None])
        dy = _wrap(y[None, None] - c[:, None, None, None])
        d = (dx ** 2 + dy ** 2).sqrt()
        profile = (r_wire ** 2 - (d - r_ring) ** 2).clamp(min=0).sqrt()  # round wire cross-section
        wire = torch.maximum(wire, profile.flatten(0, 1).amax(0) + 0.3 * r_wire * o * (profile.flatten(0, 1)
                                                                                         .amax(0) > 0))
    z = wire + 0.02 * r_wire * _smooth_noise(size, (16, 16), g)
    gap = (wire <= 0).float()
    color = torch.tensor([0.62, 0.62, 0.64]) * (1 - gap[..., None]) + 0.04 * gap[..., None]
    return color, z, 0.3 * (1 - gap) + 0.85 * gap, 1 - gap


def _polished(size, g, x, y):
    # orange-peel waviness: two octaves of smooth noise, tilts of about a degree (fixed depths in uv), so that the
    # filtered lobes stay near-delta at fine footprints and widen a little at coarse ones
    z = 0.004 * _smooth_noise(size, (8, 8), g) + 0.001 * _smooth_noise(size, (32, 32), g)
    rough = torch.full((size, size), POLISHED_ROUGHNESS)
    return torch.tensor([0.91, 0.89, 0.86]).expand(size, size, 3), z, rough, torch.ones(size, size)


_MAKERS = {"scratches": _scratches, "brushed": _brushed, "foil": _foil, "chainmail": _chainmail,
           "polished": _polished}


def detail_texture_set(kind: str, size: int = 256, seed: int = 0) -> TextureSet:
    """A texture set of `kind` (DETAIL_KINDS or POLISHED_KINDS, module docstring), size x size texels, named
    "detail_<kind>_<seed>": height the maker's displacement rescaled to [0, 1], height_scale its range in
    texture widths, normals from it."""
    if kind not in _MAKERS:
        raise InputError(f"detail texture set: unknown kind {kind!r}; expected one of "
                         f"{', '.join(DETAIL_KINDS + POLISHED_KINDS)}")
    check_int(size, "detail texture set size", 16)
    check_int(seed, "detail texture set seed", 0)
    g = torch.Generator().manual_seed(seed)
    x, y = _grid(size)
    color, z, rough, metal = _MAKERS[kind](size, g, x, y)
    scale = float(z.max() - z.min())
    height = (z - z.min()) / max(scale, 1e-12)
    return TextureSet(color=color.contiguous().clone(), normal=normals_from_height(height, max(scale, 1e-12)),
                      roughness=rough.clamp(0.02, 1).contiguous(), metalness=metal.clamp(0, 1).contiguous(),
                      height=height.contiguous(), name=f"detail_{kind}_{seed}", normal_from_height=True,
                      height_scale=max(scale, 1e-12))
