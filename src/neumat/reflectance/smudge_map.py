"""Procedural, tileable smudge and fingerprint masks for coat layers (the "fingerprints, smudges, and dust" of
Real-Time Neural Appearance Models' teapot, Fig. 1).

`smudge_map(size, seed)` is an (size, size) map in [0, 1]: `smudges` elliptical blobs (random centre, axes up to
`extent` of the tile, orientation), each filled with concentric ridges like a fingerprint's at `ridge_period`
texels, softly edged, summed and clipped; positions wrap around, so the map tiles.
"""
from __future__ import annotations

import math

import torch

from ..core.errors import InputError


def smudge_map(size: int = 256, seed: int = 0, smudges: int = 24, extent: float = 0.15,
               ridge_period: float = 3.0) -> torch.Tensor:
    """(size, size) float32 mask in [0, 1] (module docstring)."""
    if not (isinstance(size, int) and size >= 8):
        raise InputError(f"smudge_map size: expected an integer >= 8, got {size!r}")
    if not (isinstance(smudges, int) and smudges >= 0) or not 0 < extent <= 0.5 or not ridge_period >= 2:
        raise InputError(f"smudge_map: need smudges >= 0, extent in (0, 0.5], ridge_period >= 2 texels; got "
                         f"{smudges}, {extent}, {ridge_period}")
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed < 2 ** 63:
        raise InputError(f"smudge_map seed: expected an integer in [0, 2^63), got {seed!r}")
    g = torch.Generator().manual_seed(seed)
    y, x = torch.meshgrid((torch.arange(size) + 0.5) / size, (torch.arange(size) + 0.5) / size, indexing="ij")
    out = torch.zeros(size, size)
    for _ in range(smudges):
        cx, cy, a, b, angle, phase, strength = torch.rand(7, generator=g).tolist()
        dx = torch.remainder(x - cx + 0.5, 1.0) - 0.5                    # wrapped offsets: the map tiles
        dy = torch.remainder(y - cy + 0.5, 1.0) - 0.5
        c, s = math.cos(math.pi * angle), math.sin(math.pi * angle)
        ra, rb = extent * (0.4 + 0.6 * a), extent * (0.25 + 0.45 * b)
        r = torch.sqrt(((c * dx + s * dy) / ra) ** 2 + ((-s * dx + c * dy) / rb) ** 2)
        envelope = torch.exp(-(r ** 4))
        ridges = 0.5 + 0.5 * torch.cos(2 * math.pi * (r * ra * size / ridge_period + phase))
        out += (0.5 + 0.5 * strength) * envelope * ridges
    return out.clamp(0, 1)
