"""Equirectangular environment maps: the direction <-> image mapping, reading files, a procedural sky.

Mapping (Mitsuba 3's `envmap`, world y-up): a direction d = (sin theta sin phi, cos theta,
-sin theta cos phi) has image coordinates (u, v) = (phi / 2 pi, theta / pi) in [0, 1]^2; u runs along
the columns, v down the rows (row 0 is the zenith). Solid angle and image area relate by
d omega = 2 pi^2 sin(theta) du dv.
"""
from __future__ import annotations

import functools
import math
from pathlib import Path

import numpy as np
import torch

from ..core.errors import DataFormatError, InputError


def equirect_to_dir(uv: torch.Tensor) -> torch.Tensor:
    """Unit directions (N, 3) of image coordinates uv (N, 2) in [0, 1]^2."""
    theta, phi = uv[:, 1] * math.pi, uv[:, 0] * (2 * math.pi)
    st = torch.sin(theta)
    return torch.stack([st * torch.sin(phi), torch.cos(theta), -st * torch.cos(phi)], -1)


def dir_to_equirect(d: torch.Tensor) -> torch.Tensor:
    """Image coordinates uv (N, 2) in [0, 1]^2 of unit directions d (N, 3); inverse of `equirect_to_dir`."""
    # contiguous columns: atan2 on strided views misses the vectorised kernel (10x slower)
    u = torch.remainder(torch.atan2(d[:, 0].contiguous(), -d[:, 2]) / (2 * math.pi), 1.0)
    v = torch.acos(d[:, 1].clamp(-1, 1)) / math.pi
    return torch.stack([u, v], -1)


def read_envmap(path: str | Path) -> np.ndarray:
    """Read an equirectangular .hdr or .exr map as float32 (H, W, 3) linear RGB (W = 2 H expected but not
    required). Missing files raise InputError, unreadable or non-finite ones DataFormatError."""
    from ..io.images import read_image

    path = Path(path)
    if path.suffix.lower() not in (".hdr", ".exr"):
        raise InputError(f"environment map {path}: expected a .hdr or .exr file")
    if not path.is_file():
        raise InputError(f"environment map {path}: file does not exist")
    try:
        img = read_image(path)
    except InputError:
        raise
    except Exception as e:  # decoder errors of corrupt files
        raise DataFormatError(f"environment map {path}: could not decode: {type(e).__name__}: {e}") from e
    if img.ndim != 3 or img.shape[2] != 3 or min(img.shape[:2]) < 1:
        raise DataFormatError(f"environment map {path}: expected an (H, W, 3) image, got shape {img.shape}")
    if not np.isfinite(img).all():
        raise DataFormatError(f"environment map {path}: holds NaN or infinite values")
    return img.astype(np.float32)


def downsample_envmap(image: np.ndarray, width: int) -> np.ndarray:
    """Box-filtered copy (width / 2, width, 3) float32 of an equirectangular map (H, W, 3) with W >= width and
    H >= width / 2: each output texel is the mean of the input texels it covers (the trailing rows and
    columns that do not fill a whole texel are dropped). Path-traced references repeat texels, so small maps
    keep them fast."""
    image = np.asarray(image, dtype=np.float32)
    if isinstance(width, bool) or not isinstance(width, int) or width < 2 or width % 2:
        raise InputError(f"downsample_envmap width: expected an even integer >= 2, got {width!r}")
    if image.ndim != 3 or image.shape[2] != 3 or image.shape[1] < width or image.shape[0] < width // 2:
        raise InputError(f"downsample_envmap: expected an (H, W, 3) map of at least {width // 2} x {width}, "
                         f"got shape {image.shape}")
    h, w = image.shape[:2]
    fy, fx = h // (width // 2), w // width
    return image[: fy * (width // 2), : fx * width].reshape(width // 2, fy, width, fx, 3).mean((1, 3))


def sky_envmap(width: int = 512, sun_elevation: float = 35.0, sun_azimuth: float = 40.0,
               sun_irradiance: float = 3.0, sky_irradiance: float = 1.0) -> np.ndarray:
    """A procedural clear sky with a sun, float32 (width / 2, width, 3) in the mapping above.

    Sky: blue zenith to pale horizon with a glow around the sun, a dim grey-brown ground below the
    horizon. Sun: a disc of 2 degrees radius (the nearest texel on maps too coarse to hold it). Angles in
    degrees; the sun direction is (cos e sin a, sin e, cos e cos a), so azimuth 0 faces the default cameras
    (on +z). The sky (without sun) is scaled to give `sky_irradiance` on an upward-facing surface and the sun
    disc to give `sun_irradiance` at normal incidence (both RGB-averaged).
    """
    if isinstance(width, bool) or not isinstance(width, int) or width < 8 or width % 2:
        raise InputError(f"sky_envmap: width must be an even integer >= 8, got {width!r}")
    return _sky(width, float(sun_elevation), float(sun_azimuth), float(sun_irradiance), float(sky_irradiance)).copy()


@functools.lru_cache(maxsize=4)
def _sky(width: int, sun_elevation: float, sun_azimuth: float, sun_irradiance: float,
         sky_irradiance: float) -> np.ndarray:
    height = width // 2
    v = (np.arange(height) + 0.5) / height
    u = (np.arange(width) + 0.5) / width
    uu, vv = np.meshgrid(u, v)
    d = equirect_to_dir(torch.from_numpy(np.stack([uu.ravel(), vv.ravel()], -1))).numpy().reshape(height, width, 3)
    e, a = math.radians(sun_elevation), math.radians(sun_azimuth)
    sun = np.array([math.cos(e) * math.sin(a), math.sin(e), math.cos(e) * math.cos(a)])
    cos_sun = np.clip(d @ sun, -1, 1)
    up = d[..., 1:2]

    zenith, horizon, ground = np.array([0.22, 0.42, 0.95]), np.array([0.85, 0.9, 1.0]), np.array([0.3, 0.26, 0.22])
    t = np.clip(up, 0, 1) ** 0.4
    sky = horizon * (1 - t) + zenith * t
    sky = sky * (1 + 2.5 * np.exp((cos_sun[..., None] - 1) * 12))  # glow around the sun
    below = ground * 0.35 * (1 - np.exp(np.minimum(up, 0) * 20) * 0.5)
    img = np.where(up > 0, sky, below)

    solid_angle = 2 * math.pi ** 2 * np.sin(vv * math.pi) / (width * height)  # per texel
    up_irradiance = (img.mean(-1) * np.clip(up[..., 0], 0, None) * solid_angle).sum()
    img = img * (sky_irradiance / up_irradiance)

    radius = math.radians(2.0)
    disc = np.clip((cos_sun - math.cos(radius)) / (1 - math.cos(radius)) * 4, 0, 1)  # soft edge
    if not (disc * np.clip(cos_sun, 0, None)).any():  # coarse map, no texel centre on the disc: the nearest texel
        disc = (cos_sun == cos_sun.max()).astype(np.float64)
    disc_irradiance = (disc * np.clip(cos_sun, 0, None) * solid_angle).sum()
    sun_color = np.array([1.0, 0.92, 0.8]) / np.mean([1.0, 0.92, 0.8])
    img = img + disc[..., None] * sun_color * (sun_irradiance / disc_irradiance)
    return img.astype(np.float32)
