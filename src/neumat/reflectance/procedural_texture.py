"""Procedural PBR texture sets with mesoscale relief, in five material classes and many variants.

A class ("bumps", "weave", "bricks", "dents", "ridges") fixes the structure of the relief and the kind of
material; a variant fixes its parameters: feature counts and sizes, colours, roughness. Variant 0 is the
class's canonical material; variants 1, 2, ... are other materials of the same class, drawn from a
generator seeded by (class, variant), the way a measured BTF database holds several carpets or several
leathers (UBO2014 has 12 materials in each of 7 classes). The `seed` draws only the random layout (bump
centres, thread and brick noise) of a material.
"""
from __future__ import annotations

import math

import torch

from ..core.errors import InputError
from ..io.texture_set import TextureSet, normals_from_height

KINDS = ("bumps", "weave", "bricks", "dents", "ridges")
#: default relief of a procedural material's BTF: texels of displacement per height unit (CLI, benchmarks)
RELIEF = 4.0


def parse_material(spec: str) -> tuple[str, int]:
    """'kind' or 'kind~variant' -> (kind, variant)."""
    kind, _, variant = spec.partition("~")
    if kind not in KINDS or (variant and not variant.isdigit()):
        raise InputError(f"procedural material {spec!r}: expected one of {', '.join(KINDS)}, optionally followed by "
                         "~<variant number> (e.g. bricks~3)")
    return kind, int(variant or 0)


def material_name(kind: str, variant: int) -> str:
    """The name of a variant: the class for variant 0, else 'kind~variant'."""
    return kind if variant == 0 else f"{kind}~{variant}"


def _random_color(g: torch.Generator, saturation: tuple[float, float], value: tuple[float, float]
                  ) -> tuple[float, float, float]:
    """A colour of uniform hue and saturation / value uniform in the given ranges (HSV -> RGB)."""
    h, s, v = (float(t) for t in torch.rand(3, generator=g))
    s = saturation[0] + s * (saturation[1] - saturation[0])
    v = value[0] + v * (value[1] - value[0])
    k = torch.tensor([5.0, 3.0, 1.0]) + h * 6
    rgb = v - v * s * (torch.minimum(k % 6, 4 - k % 6)).clamp(0, 1)
    return tuple(float(c) for c in rgb)


def material_parameters(kind: str, variant: int = 0) -> dict:
    """The parameters of a material of class `kind`: the canonical ones for variant 0, else drawn."""
    if kind not in KINDS:
        raise InputError(f"procedural_texture_set kind {kind!r}: expected one of {', '.join(KINDS)}")
    if variant < 0:
        raise InputError(f"procedural_texture_set variant: expected >= 0, got {variant}")
    if variant == 0:
        return {
            "bumps": dict(count=8, radius=0.09, colors=((0.6, 0.15, 0.1), (0.9, 0.8, 0.3)), rough=(0.25, 0.3)),
            "weave": dict(threads=4, colors=((0.1, 0.2, 0.6), (0.7, 0.6, 0.5)), rough=0.6, jitter=0.4),
            "bricks": dict(rows=4, per_row=2, mortar=(0.08, 0.12), colors=((0.55, 0.22, 0.12), (0.75, 0.75, 0.7)),
                           rough=(0.7, 0.2), noise=0.2),
            "dents": dict(count=10, radius=0.07, color=(0.9, 0.65, 0.35), rough=(0.2, 0.2)),
            "ridges": dict(frequency=(5, 0), warp=0.5, colors=((0.2, 0.5, 0.25), (0.85, 0.9, 0.8)),
                           rough=(0.35, 0.2)),
        }[kind]
    g = torch.Generator().manual_seed(1000 * (KINDS.index(kind) + 1) + variant)

    def uniform(lo: float, hi: float) -> float:
        return lo + (hi - lo) * float(torch.rand((), generator=g))

    def integer(lo: int, hi: int) -> int:
        return int(torch.randint(lo, hi + 1, (), generator=g))

    def color(saturation=(0.2, 0.9), value=(0.2, 0.9)):
        return _random_color(g, saturation, value)

    if kind == "bumps":
        return dict(count=integer(5, 14), radius=uniform(0.06, 0.12), colors=(color(), color()),
                    rough=(uniform(0.1, 0.45), uniform(0.1, 0.4)))
    if kind == "weave":
        return dict(threads=integer(3, 6), colors=(color(), color()), rough=uniform(0.4, 0.85),
                    jitter=uniform(0.2, 0.5))
    if kind == "bricks":
        return dict(rows=2 * integer(1, 3), per_row=integer(1, 3), mortar=(uniform(0.05, 0.12), uniform(0.08, 0.16)),
                    colors=(color(), color(saturation=(0.0, 0.2), value=(0.5, 0.85))),
                    rough=(uniform(0.5, 0.85), uniform(0.05, 0.25)), noise=uniform(0.1, 0.3))
    if kind == "dents":
        return dict(count=integer(6, 16), radius=uniform(0.05, 0.1), color=color((0.0, 0.6), (0.6, 0.95)),
                    rough=(uniform(0.1, 0.35), uniform(0.1, 0.3)))
    return dict(frequency=(integer(3, 8), integer(0, 2)), warp=uniform(0.0, 1.0), colors=(color(), color()),
                rough=(uniform(0.2, 0.5), uniform(0.1, 0.3)))


def procedural_texture_set(kind: str, size: int = 32, seed: int = 0, variant: int = 0) -> TextureSet:
    """A synthetic PBR texture set (size x size texels, height in [0, 1]) for tests, examples and benchmarks.

    kinds: "bumps" (random round bumps, plastic), "weave" (over-under threads, cloth), "bricks" (raised bricks
    and mortar grooves), "dents" (dented metal), "ridges" (parallel grooves, anisotropic relief). `variant`
    picks the material within the class (module docstring), `seed` its random layout. Tiles seamlessly.
    """
    p = material_parameters(kind, variant)
    g = torch.Generator().manual_seed(seed)
    y, x = torch.meshgrid((torch.arange(size) + 0.5) / size, (torch.arange(size) + 0.5) / size, indexing="ij")

    def blobs(count: int, radius: float) -> torch.Tensor:
        c = torch.rand(count, 2, generator=g)
        dx = (x[None] - c[:, 0, None, None] + 0.5) % 1 - 0.5
        dy = (y[None] - c[:, 1, None, None] + 0.5) % 1 - 0.5
        return torch.exp(-(dx ** 2 + dy ** 2) / radius ** 2).amax(0)

    def tint(a, b, t):
        return torch.tensor(a) * (1 - t[..., None]) + torch.tensor(b) * t[..., None]

    metal = torch.zeros(size, size)
    if kind == "bumps":
        height = blobs(p["count"], p["radius"])
        color = tint(*p["colors"], height)
        rough = p["rough"][0] + p["rough"][1] * (1 - height)
    elif kind == "weave":
        n = p["threads"]
        a, b = torch.sin(math.pi * n * 2 * x), torch.sin(math.pi * n * 2 * y)
        warp = (torch.cos(math.pi * n * 2 * y) > 0).float()
        jitter = (1 - p["jitter"]) + p["jitter"] * torch.rand(size, size, generator=g)
        height = 0.5 + 0.5 * torch.where(warp > 0, a.abs(), b.abs()) * jitter
        color = torch.where(warp[..., None] > 0, torch.tensor(p["colors"][0]), torch.tensor(p["colors"][1]))
        rough = torch.full((size, size), p["rough"])
    elif kind == "bricks":
        rows = (y * p["rows"]).floor()
        shift = (rows % 2) * 0.5 / p["per_row"]
        u = (x + shift) * p["per_row"] % 1
        v = y * p["rows"] % 1
        mortar = ((u < p["mortar"][0]) | (v < p["mortar"][1])).float()
        height = (1 - mortar) * ((1 - p["noise"]) + p["noise"] * torch.rand(size, size, generator=g))
        color = tint(*p["colors"], mortar)
        rough = p["rough"][0] + p["rough"][1] * mortar
    elif kind == "dents":
        height = 1 - blobs(p["count"], p["radius"])
        color = torch.tensor(p["color"]).expand(size, size, 3).clone()
        metal = torch.ones(size, size)
        rough = p["rough"][0] + p["rough"][1] * (1 - height)
    else:
        fx, fy = p["frequency"]
        wobble = torch.sin(2 * math.pi * (y if fy == 0 else x))          # along the ridges
        height = 0.5 + 0.5 * torch.sin((2 * math.pi * fx) * x + (2 * math.pi * fy) * y + p["warp"] * wobble)
        color = tint(*p["colors"], height)
        rough = p["rough"][0] + p["rough"][1] * height
    return TextureSet(color=color.float().contiguous(), normal=normals_from_height(height, 0.02),
                      roughness=rough.float().clamp(0.05, 1).contiguous(), metalness=metal.contiguous(),
                      height=height.float().contiguous(), name=material_name(kind, variant),
                      normal_from_height=True, height_scale=0.02)
