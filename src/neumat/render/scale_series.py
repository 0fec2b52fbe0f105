"""The multi-scale evaluation scene of Timonen et al. 2025 (Sec. 5.2, Fig. 4, Table 6): a textured plane seen at a
geometric series of texture scales x directional lights x camera tilts, scored per scale with FLIP.

Each image is one sample through each pixel centre (no jitter: the material filters by the pixel footprint) with
light sampling of one directional light. Scale i sets the plane's `uv_scale` so that a pixel at the centre of the
head-on image covers `texels_per_pixel[i]` texels, geometrically from 1/8 texel to 2 whole textures per pixel;
the tilted cameras see larger and more elongated footprints towards the horizon. A reference with Monte Carlo
footprint filtering (an SVBRDF) has noise of its own: `score_scale_series` renders it twice and reports the FLIP
between the two renders as the noise floor. A model equal to the reference's expectation scores below it (it
adds no noise of its own), so differences between models well above the floor are not Monte Carlo noise.
"""
from __future__ import annotations

import math

import numpy as np
import torch

from ..core.errors import InputError
from ..core.material import Material
from ..metrics.image import image_metrics
from .render import render

#: the benchmark's directional lights (direction towards the light, y up)
LIGHTS = ["dir:0.3/1/0.2", "dir:-0.8/0.6/0.3", "dir:0.5/0.4/-0.9", "dir:0/0.35/1"]
#: camera tilts from the plane's normal (degrees)
TILTS = [0.0, 35.0, 65.0]
#: camera distance from the origin (world units) and field of view (degrees)
DISTANCE, FOV = 3.0, 40.0


def plane_scales(n: int, resolution: int, texels: int) -> list[float]:
    """n uv_scale values (texture repeats per world unit) from 1/8 texel to 2 textures per pixel at the centre of
    the head-on image, geometric, for a `resolution`-pixel image of a texture `texels` wide."""
    if n < 1 or resolution < 1 or texels < 1:
        raise InputError(f"plane_scales: expected n, resolution and texels >= 1, got {n}, {resolution}, {texels}")
    visible = 2 * DISTANCE * math.tan(math.radians(FOV) / 2)  # world units across the image
    lo = resolution / (8 * visible * texels)
    hi = 2 * resolution / visible
    return [float(s) for s in np.geomspace(lo, hi, n)]


def texels_per_pixel(scales: list[float], resolution: int, texels: int) -> list[float]:
    """Texels across one pixel at the centre of the head-on image for each uv_scale of `scales`."""
    visible = 2 * DISTANCE * math.tan(math.radians(FOV) / 2)
    return [s * visible / resolution * texels for s in scales]


def render_scale_series(material: Material, scales: list[float], lights: list[str], tilts: list[float],
                        resolution: int, device) -> list[torch.Tensor]:
    """Images (resolution, resolution, 3) on the CPU of the plane with `material`, scale-major, then light, then
    tilt: len(scales) * len(lights) * len(tilts) images."""
    images = []
    for s in scales:
        for light in lights:
            for tilt in tilts:
                images.append(render(material, scene="plane", light=light, spp=1, resolution=resolution,
                                     strategy="light", jitter=False, device=device, tilt=tilt, distance=DISTANCE,
                                     fov=FOV, uv_scale=float(s)).cpu())
    return images


def per_scale_flip(reference: list[torch.Tensor], images: list[torch.Tensor], n_scales: int) -> list[float]:
    """Mean FLIP of each scale's images (lists of n_scales * k images in `render_scale_series` order)."""
    if len(reference) != len(images) or len(images) % n_scales:
        raise InputError(f"per_scale_flip: expected two lists of n_scales x k images, got {len(reference)} and "
                         f"{len(images)} for {n_scales} scales")
    flips = [image_metrics(r, m)["flip"] for r, m in zip(reference, images)]
    k = len(flips) // n_scales
    return [float(np.mean(flips[i * k:(i + 1) * k])) for i in range(n_scales)]


def score_scale_series(model: Material, reference: Material, n_scales: int = 9, resolution: int = 48,
                       lights: list[str] | None = None, tilts: list[float] | None = None, device="cpu") -> dict:
    """Score `model` against a textured `reference` (a Material with `textures`, e.g. an SVBRDF) on the plane
    scene: {"texels_per_pixel": [..], "flip": per-scale FLIP [..], "flip_mean", "floor": the per-scale FLIP of the
    reference against a second render of itself [..], "floor_mean"}, each list of length n_scales (scale 0 the
    finest). Defaults: the benchmark's 4 lights (`LIGHTS`) and 3 tilts (`TILTS`)."""
    size = getattr(getattr(reference, "textures", None), "size", None)
    if size is None:
        raise InputError(f"the scale series needs a textured reference (a texture-set folder), got "
                         f"{getattr(reference, 'name', type(reference).__name__)}")
    lights, tilts = lights or LIGHTS, tilts or TILTS
    texels = int(max(size))
    scales = plane_scales(n_scales, resolution, texels)
    ref = render_scale_series(reference, scales, lights, tilts, resolution, device)
    again = render_scale_series(reference, scales, lights, tilts, resolution, device)
    images = render_scale_series(model, scales, lights, tilts, resolution, device)
    flip, floor = per_scale_flip(ref, images, n_scales), per_scale_flip(ref, again, n_scales)
    return {"texels_per_pixel": texels_per_pixel(scales, resolution, texels), "flip": flip,
            "flip_mean": float(np.mean(flip)), "floor": floor, "floor_mean": float(np.mean(floor))}
