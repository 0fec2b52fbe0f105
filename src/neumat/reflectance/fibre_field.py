"""Fibre directions over a texture, for the anisotropic (fibre) shading of generated BTFs.

A fibre field is stored as the doubled angle (cos 2a, sin 2a) (H, W, 2) of the fibre angle a in the texture
plane (radians from +s, the columns' direction, towards +t, up the rows), so that the direction a and its
opposite a + pi are one orientation and bilinear lookup blends orientations without cancelling them.
"""
from __future__ import annotations

import math

import torch

from ..core.errors import InputError


def _wrap_blur(x: torch.Tensor, sigma: float) -> torch.Tensor:
    """Separable Gaussian blur of x (H, W) with wrap-around, std `sigma` texels."""
    r = max(1, int(math.ceil(3 * sigma)))
    k = torch.exp(-0.5 * (torch.arange(-r, r + 1, dtype=x.dtype) / sigma) ** 2)
    k = k / k.sum()
    for dim in (0, 1):
        x = sum(w * torch.roll(x, i, dim) for i, w in zip(range(-r, r + 1), k.tolist()))
    return x


def fibre_field(height: torch.Tensor, kind: str = "grain", sigma: float = 2.0) -> torch.Tensor:
    """Doubled-angle fibre field (H, W, 2) of a texture with height map `height` (H, W).

    kind: "grain": along the height map's ridges and grooves, i.e. across its dominant local gradient (the
    structure tensor's minor eigenvector, window std `sigma` texels; along +s where the height is flat);
    "weave:<p>": a plain weave of p x p-texel cells, fibres along s in the cells where (row // p + col // p)
    is even and along t elsewhere; "angle:<deg>": one direction everywhere.
    """
    if height.dim() != 2:
        raise InputError(f"fibre_field height: expected an (H, W) map, got shape {tuple(height.shape)}")
    h, w = height.shape
    z = height.float()
    if kind == "grain":
        gs = (torch.roll(z, -1, 1) - torch.roll(z, 1, 1)) / 2
        gt = -(torch.roll(z, -1, 0) - torch.roll(z, 1, 0)) / 2
        jss, jtt, jst = (_wrap_blur(a, sigma) for a in (gs * gs, gt * gt, gs * gt))
        v = torch.stack([jtt - jss, -2 * jst], -1)           # doubled angle of the gradient's normal direction
        norm = v.norm(dim=-1, keepdim=True)
        flat = torch.tensor([1.0, 0.0]).expand(h, w, 2)
        return torch.where(norm > 1e-12 * float(z.abs().max() + 1) ** 2, v / norm.clamp(min=1e-30), flat)
    if kind.startswith("weave:") or kind.startswith("angle:"):
        try:
            value = float(kind.split(":", 1)[1])
        except ValueError:
            value = float("nan")
        if kind.startswith("angle:"):
            if not math.isfinite(value):
                raise InputError(f"fibre_field kind {kind!r}: expected angle:<degrees>")
            a = math.radians(2 * value)
            return torch.tensor([math.cos(a), math.sin(a)]).expand(h, w, 2).clone()
        if not (value >= 1 and value == int(value)):
            raise InputError(f"fibre_field kind {kind!r}: expected weave:<cell size in texels, an integer >= 1>")
        p = int(value)
        rows, cols = torch.meshgrid(torch.arange(h), torch.arange(w), indexing="ij")
        along_s = ((rows // p + cols // p) % 2 == 0)[..., None]
        return torch.where(along_s, torch.tensor([1.0, 0.0]), torch.tensor([-1.0, 0.0]))
    raise InputError(f"fibre_field kind: expected 'grain', 'weave:<p>' or 'angle:<deg>', got {kind!r}")


def fibre_tangents(doubled: torch.Tensor) -> torch.Tensor:
    """Fibre directions (N, 3) in the texture plane (z = 0) from doubled-angle samples (N, 2)."""
    a = 0.5 * torch.atan2(doubled[:, 1], doubled[:, 0])
    return torch.stack([torch.cos(a), torch.sin(a), torch.zeros_like(a)], -1)
