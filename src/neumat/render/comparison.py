"""Image metrics of a material against its reference under one rendering protocol, with the reference's own
noise floor.

Protocol: the sphere under the sky, direct light, `strategy="mis-lobes"` (light sampling and a fixed,
material-independent lobe mixture, so both renders use the same directions) and `sampler="sobol"`
(randomly shifted quasi-random points per pixel). The floor is the same metrics of the reference against
itself rendered with the next seed: errors near it are noise, not the material.

Measured on MERL-like tables (128^2, 1024 spp): with the default "mis" strategy and independent numbers the
floor was SSIM 0.35 / MAE 0.042 at 64 spp (blue-metallic-paint2: a glossy lobe that cosine sampling of the
table misses, so every rendering is mostly fireflies); this protocol gives SSIM 0.991 / MAE 0.0023 at 64 spp
and SSIM 0.9998 / MAE 0.00034 at 1024 spp (chrome: 0.998 / 0.0009).
"""
from __future__ import annotations

from ..core.material import Material
from ..metrics.image import image_metrics
from .render import render

#: the comparison renderings' strategy and sampler (module docstring)
COMPARISON_SAMPLING = dict(strategy="mis-lobes", sampler="sobol")
COMPARISON_OPTIONS = dict(scene="sphere", **COMPARISON_SAMPLING)
#: how tables name the reference rendered again with the next seed (the noise floor)
FLOOR_NAME = "reference, seed + 1"


def comparison_images(materials: dict[str, Material], spp: int, resolution: int, seed: int = 0, device=None,
                      progress: bool = False) -> dict:
    """Renders (resolution, resolution, 3) of each material under the comparison protocol with `seed`."""
    return {name: render(m, spp=spp, resolution=(resolution, resolution), seed=seed, device=device,
                         progress=progress, **COMPARISON_OPTIONS) for name, m in materials.items()}


def reference_renders(reference: Material, spp: int, resolution: int, seed: int = 0, device=None) -> tuple:
    """The reference rendered with `seed` and with seed + 1 (the second one measures the noise floor)."""
    return tuple(comparison_images({"ref": reference}, spp, resolution, s, device)["ref"] for s in (seed, seed + 1))


def image_comparison(material: Material, reference: Material, spp: int, resolution: int, seed: int = 0,
                     device=None, floor: bool = True, renders: tuple | None = None) -> dict[str, float]:
    """`image_metrics` keys of `material` against `reference`, and with `floor` the same keys prefixed
    "floor_" for the reference against itself at seed + 1. renders: `reference_renders` of the same settings,
    when several materials are compared with one reference (else rendered here)."""
    if renders is None:
        renders = reference_renders(reference, spp, resolution, seed, device) if floor else \
            (comparison_images({"ref": reference}, spp, resolution, seed, device)["ref"],)
    test = comparison_images({"test": material}, spp, resolution, seed, device)["test"]
    out = image_metrics(renders[0], test)
    if floor:
        out.update({f"floor_{k}": v for k, v in image_metrics(renders[0], renders[1]).items()})
    return out
