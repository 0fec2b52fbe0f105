"""Image metrics of a material against its reference under one rendering protocol, with the reference's own
noise floor scored the same way.

Protocol (`PROTOCOL`): the sphere under the sky, direct light, `strategy="mis-lobes"` (light sampling and a fixed,
material-independent lobe mixture) and `sampler="sobol"` (randomly shifted quasi-random points per pixel). The
material and the reference are each rendered at `spp` with `seed` and both scored against the reference rendered at
`REFERENCE_FACTOR` x spp with seed + 1 (its own error is about 1/4 of one render's, independent of both): the
reference's score is the floor, what a perfect model gets; errors near it are noise, not the material. (Scoring
the material against a same-seed reference while the floor compares two seeds made the floor worse than the model,
e.g. SSIM 0.51 against 0.99, and meaningless.) The reference's negative values (measured noise) count as 0, as in
every fit's targets (`core.material.NonNegative`; docs/render.md).

Measured on MERL-like tables (128^2, 1024 spp): with the default "mis" strategy and independent numbers one render
against another was SSIM 0.35 / MAE 0.042 at 64 spp (blue-metallic-paint2: a glossy lobe that cosine sampling of
the table misses); with this strategy and sampler SSIM 0.991 / MAE 0.0023 at 64 spp.
"""
from __future__ import annotations

import copy

import torch

from ..core.material import Material, NonNegative
from ..metrics.image import image_metrics
from .render import render

#: the comparison renderings' strategy and sampler (module docstring)
COMPARISON_SAMPLING = dict(strategy="mis-lobes", sampler="sobol")
COMPARISON_OPTIONS = dict(scene="sphere", **COMPARISON_SAMPLING)
#: the scoring reference's samples per pixel, as a multiple of the compared renders'
REFERENCE_FACTOR = 16
#: how tables name the reference scored like a model (the noise floor)
FLOOR_NAME = "floor (reference at spp)"
#: the protocol in one line, for tables and results files
PROTOCOL = (f"sphere under the sky, mis-lobes + sobol; model and reference each rendered at spp (seed s) and "
            f"scored against the reference at {REFERENCE_FACTOR}x spp (seed s+1; a Monte Carlo footprint filter at "
            f"1/{REFERENCE_FACTOR} of its positions per evaluation); floor = the reference's score")


def comparison_images(materials: dict[str, Material], spp: int, resolution: int, seed: int = 0, device=None,
                      progress: bool = False) -> dict:
    """Renders (resolution, resolution, 3) of each material under the comparison protocol with `seed`."""
    return {name: render(m, spp=spp, resolution=(resolution, resolution), seed=seed, device=device,
                         progress=progress, **COMPARISON_OPTIONS) for name, m in materials.items()}


def reference_renders(reference: Material, spp: int, resolution: int, seed: int = 0, device=None) -> tuple:
    """(the scoring reference: `reference` at REFERENCE_FACTOR x spp with seed + 1, `reference` at spp with seed:
    scored against the first, the floor), negative values read as 0 (module docstring). A reference that filters
    its footprint by Monte Carlo (a texture set's SVBRDF: 256 positions an evaluation) renders the first with
    1 / REFERENCE_FACTOR of its positions (`per_pixel_footprint_budget`): as many per pixel as the floor, 16x
    cheaper (about 3 instead of 50 CPU minutes for a 256^2 set at 128^2 x 1024 spp), and as converged: the
    seed-to-seed MSE of 16-spp renders is the same at 16 and at 256 positions (Wood092 6.76e-4, Metal027 7.98e-6),
    the light and lobe sampling's noise dominating."""
    converged = NonNegative(per_pixel_footprint_budget(reference, REFERENCE_FACTOR))
    return (comparison_images({"ref": converged}, REFERENCE_FACTOR * spp, resolution, seed + 1, device)["ref"],
            comparison_images({"ref": NonNegative(reference)}, spp, resolution, seed, device)["ref"])


def per_pixel_footprint_budget(material: Material, factor: int) -> Material:
    """`material` with 1 / factor of its Monte Carlo footprint positions per evaluation (at least 1), for a render
    at factor x spp: the same positions per pixel. Materials that filter by Monte Carlo keep the count in an int
    `samples` and draw from their `generator` (`neumat.reflectance.footprint_filter.filtered_eval`'s arguments); others
    are returned as they are. The copy shares the maps and draws from a generator of the same seed."""
    samples, generator = getattr(material, "samples", None), getattr(material, "generator", None)
    if not isinstance(samples, int) or isinstance(samples, bool) or not isinstance(generator, torch.Generator):
        return material
    out = copy.copy(material)
    out.samples = max(1, samples // factor)
    out.generator = torch.Generator(device=generator.device).manual_seed(generator.initial_seed())
    return out


def image_comparison(material: Material, reference: Material, spp: int, resolution: int, seed: int = 0,
                     device=None, floor: bool = True, renders: tuple | None = None) -> dict[str, float]:
    """`image_metrics` keys of `material` (rendered at spp with `seed`) against the converged reference, and with
    `floor` the same keys prefixed "floor_" for the reference rendered like the material (module docstring).
    renders: `reference_renders` of the same settings, when several materials are compared with one reference
    (else rendered here)."""
    return compared_images(material, reference, spp, resolution, seed, device, floor, renders)[0]


def compared_images(material: Material, reference: Material, spp: int, resolution: int, seed: int = 0,
                    device=None, floor: bool = True, renders: tuple | None = None
                    ) -> tuple[dict[str, float], tuple, torch.Tensor]:
    """`image_comparison`'s scores with the renderings they score, for a caller that shows them (a picture):
    (scores, the reference renders (the scoring reference, and with `floor` the floor), the material's rendering)."""
    if renders is None:
        renders = reference_renders(reference, spp, resolution, seed, device) if floor else \
            (comparison_images({"ref": NonNegative(reference)}, REFERENCE_FACTOR * spp, resolution, seed + 1,
                               device)["ref"],)
    test = comparison_images({"test": material}, spp, resolution, seed, device)["test"]
    out = image_metrics(renders[0], test)
    if floor:
        out.update({f"floor_{k}": v for k, v in image_metrics(renders[0], renders[1]).items()})
    return out, renders, test
