"""`render`: one call from a Material to an image (direct illumination, batched over pixels x samples)."""
from __future__ import annotations

import torch

from ..core.checks import check_device, check_int, check_memory
from ..core.errors import InputError
from ..core.material import Material, material_device
from .integrators import check_strategy, shade_direct
from .lights import Light, make_light
from .scenes import make_scene

#: pixel samples traced per batch (bounds memory; the batch is split into whole pixels where spp allows)
BATCH_SAMPLES = 1 << 18
#: the same on CPU, where a smaller batch keeps the working set in cache (about 1.5x faster than 2^18)
CPU_BATCH_SAMPLES = 1 << 16
#: ways of drawing the uniform numbers of the pixel samples (`render`'s sampler)
SAMPLERS = ("random", "sobol")


def render(material: Material, scene: str = "sphere", light: str | Light = "env:sky", spp: int = 64,
           resolution: tuple[int, int] | int = (256, 256), strategy: str = "mis", seed: int = 0, device=None,
           progress: bool = False, sampler: str = "random", **scene_options) -> torch.Tensor:
    """Render `material` and return a float32 (H, W, 3) linear RGB image on `device`.

    scene: "sphere", "plane" or "mesh:PATH", optionally with ",key=value" options (`neumat.render.scenes`);
    light: "point", "dir", "const:VALUE", "env:PATH" or "env:sky" (`neumat.render.lights`), or a `Light`
    whose tensors live on `device`;
    resolution: (width, height) or one int for a square image; strategy: "mis", "light", "material" or
    "mis-lobes" (`neumat.render.integrators`);
    sampler: "random" (independent uniform numbers) or "sobol" (every pixel's samples are the first spp points
    of one scrambled 6D Sobol sequence, shifted modulo 1 by a random offset per pixel, and per batch of its
    samples where spp exceeds batch_size: unbiased, and its error falls faster than 1 / sqrt(spp) where the
    integrand is smooth);
    device: torch device (default: the material's, `core.material.material_device`, else CPU). Results are
    deterministic for a given seed, device and batch size. Keyword options go to the scene, except the
    render options `jitter` (bool, default True: sample positions uniformly over each pixel, a box
    filter; False: every sample through the pixel centre, for materials that filter by the footprint
    themselves) and `batch_size` (pixel samples per batch, default CPU_BATCH_SAMPLES on CPU, else
    BATCH_SAMPLES).
    """
    if not isinstance(material, Material) and not all(hasattr(material, a) for a in ("eval", "can_sample")):
        raise InputError(f"material: expected a neumat Material, got {type(material).__name__}")
    if getattr(material, "full_sphere", False):
        raise InputError(f"material {getattr(material, 'name', '?')!r}: the renderer shades reflectance "
                         "(BRDF) materials; full-sphere (translucent) materials are not supported")
    check_int(spp, "spp")
    check_strategy(strategy)
    if sampler not in SAMPLERS:
        raise InputError(f"sampler: expected one of {', '.join(SAMPLERS)}, got {sampler!r}")
    width, height = _resolution(resolution)
    jitter = bool(scene_options.pop("jitter", True))
    device = check_device(device) if device is not None else material_device(material)
    check_memory(width * height * 3 * 4 * 4, f"a {width} x {height} image")
    batch = scene_options.pop("batch_size", CPU_BATCH_SAMPLES if device.type == "cpu" else BATCH_SAMPLES)
    check_int(batch, "batch_size")

    the_scene = make_scene(scene, (width, height), **scene_options)
    the_light = light if isinstance(light, Light) else make_light(light, device=device)
    gen = torch.Generator(device=device).manual_seed(int(seed))
    n_pixels = width * height
    points = _sobol_points(spp, seed, device) if sampler == "sobol" else None
    image = torch.zeros(n_pixels, 3, dtype=torch.float32, device=device)
    spp_chunk = min(spp, batch)
    pixel_chunk = max(1, batch // spp_chunk)
    chunks = [(p0, s0) for p0 in range(0, n_pixels, pixel_chunk) for s0 in range(0, spp, spp_chunk)]

    with torch.no_grad(), _progress(progress, len(chunks), f"render {scene} / {light}") as advance:
        for p0, s0 in chunks:
            pix = torch.arange(p0, min(p0 + pixel_chunk, n_pixels), device=device)
            ns = min(spp_chunk, spp - s0)
            u = _uniforms(len(pix) * ns, gen, None if points is None else points[s0:s0 + ns])
            image[pix] += _render_chunk(material, the_scene, the_light, pix, ns, width, jitter, strategy,
                                        u).reshape(-1, ns, 3).sum(1)
            advance()
    return (image / spp).reshape(height, width, 3)


def _sobol_points(spp: int, seed: int, device) -> torch.Tensor:
    """The first spp points (spp, 6) float64 of a scrambled 6D Sobol sequence (scrambling seeded by `seed`)."""
    engine = torch.quasirandom.SobolEngine(6, scramble=True, seed=int(seed))
    return engine.draw(spp, dtype=torch.float64).to(device)


def _uniforms(n: int, gen: torch.Generator, points: torch.Tensor | None) -> torch.Tensor:
    """(n, 6) float64 uniform numbers for n = P * ns pixel samples: independent (points None), or the ns
    Sobol points (ns, 6) shifted modulo 1 by one random offset per pixel (Cranley-Patterson rotation)."""
    device = gen.device
    if points is None:
        return torch.rand(n, 6, generator=gen, device=device, dtype=torch.float64)  # float64: full texel resolution
    shift = torch.rand(n // len(points), 1, 6, generator=gen, device=device, dtype=torch.float64)
    return torch.remainder(points.unsqueeze(0) + shift, 1.0).reshape(n, 6)


def _render_chunk(material, scene, light, pix, ns, width, jitter, strategy, u) -> torch.Tensor:
    """Radiance (P * ns, 3) of ns samples in each pixel of `pix` (flat indices), u (P * ns, 6) uniforms."""
    device = pix.device
    n = pix.shape[0] * ns
    offset = u[:, 4:6].float() if jitter else torch.full((n, 2), 0.5, device=device)
    pixel_xy = torch.stack([pix % width, pix // width], -1).repeat_interleave(ns, 0).to(torch.float32)
    rays = scene.camera.rays(pixel_xy + offset)
    hits = scene.intersect(rays, with_uv=bool(getattr(material, "spatially_varying", False)))
    out = torch.zeros(n, 3, dtype=torch.float32, device=device)
    miss = ~hits.mask
    if bool(miss.any()):
        out[miss] = light.background(rays.d[miss])
    if bool(hits.mask.any()):
        out[hits.mask] = shade_direct(material, light, scene, hits, -rays.d[hits.mask], u[hits.mask, :4], strategy)
    return out


def _resolution(resolution) -> tuple[int, int]:
    if isinstance(resolution, int) and not isinstance(resolution, bool):
        resolution = (resolution, resolution)
    try:
        width, height = (int(r) for r in resolution)
    except (TypeError, ValueError):
        raise InputError(f"resolution: expected (width, height) or an int, got {resolution!r}") from None
    if width < 1 or height < 1:
        raise InputError(f"resolution: expected positive width and height, got {resolution!r}")
    return width, height


class _progress:
    """Context manager yielding an `advance()` callable: a rich progress bar, or a no-op."""

    def __init__(self, enabled: bool, total: int, label: str) -> None:
        self.enabled, self.total, self.label = enabled, total, label

    def __enter__(self):
        if not self.enabled:
            return lambda: None
        from rich.progress import Progress
        self.bar = Progress(transient=True)
        self.bar.start()
        task = self.bar.add_task(self.label, total=self.total)
        return lambda: self.bar.advance(task)

    def __exit__(self, *exc) -> None:
        if self.enabled:
            self.bar.stop()
