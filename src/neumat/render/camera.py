"""Orthographic and pinhole cameras that turn pixel positions into rays with ray differentials.

Pixel coordinates: x to the right in [0, width], y downwards in [0, height]; pixel (row i, column j)
covers [j, j + 1] x [i, i + 1]. The world is y-up (Mitsuba's convention). The image plane spans
[-aspect, aspect] x [-1, 1] in normalised units, aspect = width / height, scaled by `half_height`
(orthographic, world units) or tan(fov / 2) (pinhole, vertical field of view).
"""
from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass

import torch

from ..core.errors import InputError


@dataclass
class Rays:
    """A batch of N rays and their differentials with respect to the pixel coordinates x and y.

    o, d: (N, 3) origins and unit directions; do_dx, do_dy, dd_dx, dd_dy: (N, 3) per pixel unit.
    """

    o: torch.Tensor
    d: torch.Tensor
    do_dx: torch.Tensor
    do_dy: torch.Tensor
    dd_dx: torch.Tensor
    dd_dy: torch.Tensor

    def __getitem__(self, index) -> "Rays":
        return Rays(*(getattr(self, k)[index] for k in ("o", "d", "do_dx", "do_dy", "dd_dx", "dd_dy")))


class Camera(ABC):
    """Look-at frame shared by both projections: `origin` looks at `target`, `up` tilts the image."""

    def __init__(self, width: int, height: int, origin, target, up=(0.0, 1.0, 0.0)) -> None:
        if int(width) < 1 or int(height) < 1:
            raise InputError(f"camera resolution: expected positive width and height, got {width} x {height}")
        self.width, self.height = int(width), int(height)
        self.origin = torch.tensor(origin, dtype=torch.float64)
        forward = torch.tensor(target, dtype=torch.float64) - self.origin
        if forward.norm() == 0:
            raise InputError("camera: origin and target coincide")
        self.forward = forward / forward.norm()
        right = torch.linalg.cross(self.forward, torch.tensor(up, dtype=torch.float64))
        if right.norm() < 1e-9:
            raise InputError(f"camera: up vector {up} is parallel to the viewing direction")
        self.right = right / right.norm()
        self.up = torch.linalg.cross(self.right, self.forward)

    def _screen(self, pixels: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Normalised image-plane coordinates (sx, sy), each (N,), of pixel positions (N, 2)."""
        if pixels.dim() != 2 or pixels.shape[1] != 2:
            raise InputError(f"pixels: expected shape (N, 2), got {tuple(pixels.shape)}")
        sx = (2 * pixels[:, 0] - self.width) / self.height
        sy = (self.height - 2 * pixels[:, 1]) / self.height
        return sx, sy

    def _vec(self, v: torch.Tensor, like: torch.Tensor) -> torch.Tensor:
        return v.to(device=like.device, dtype=like.dtype)

    @abstractmethod
    def rays(self, pixels: torch.Tensor) -> Rays:
        """Rays through pixel positions (N, 2); device and dtype follow `pixels`."""


class OrthographicCamera(Camera):
    """Parallel rays along the viewing direction; the image plane spans +-half_height world units vertically."""

    def __init__(self, width: int, height: int, origin, target, up=(0.0, 1.0, 0.0), half_height: float = 1.0):
        super().__init__(width, height, origin, target, up)
        if not half_height > 0:
            raise InputError(f"orthographic camera: half_height must be > 0, got {half_height}")
        self.half_height = float(half_height)

    def rays(self, pixels: torch.Tensor) -> Rays:
        sx, sy = self._screen(pixels)
        r, u, f = (self._vec(v, pixels) for v in (self.right, self.up, self.forward))
        o = self._vec(self.origin, pixels) + self.half_height * (sx[:, None] * r + sy[:, None] * u)
        n = pixels.shape[0]
        scale = 2 * self.half_height / self.height
        zero = torch.zeros_like(o)
        return Rays(o, f.expand(n, 3), (scale * r).expand(n, 3), (-scale * u).expand(n, 3), zero, zero)


class PinholeCamera(Camera):
    """Perspective rays from `origin`; `fov` is the vertical field of view in degrees."""

    def __init__(self, width: int, height: int, origin, target, up=(0.0, 1.0, 0.0), fov: float = 30.0):
        super().__init__(width, height, origin, target, up)
        if not 0 < fov < 180:
            raise InputError(f"pinhole camera: fov must lie in (0, 180) degrees, got {fov}")
        self.tan_half = math.tan(math.radians(fov) / 2)

    def rays(self, pixels: torch.Tensor) -> Rays:
        sx, sy = self._screen(pixels)
        r, u, f = (self._vec(v, pixels) for v in (self.right, self.up, self.forward))
        c = f + self.tan_half * (sx[:, None] * r + sy[:, None] * u)
        length = c.norm(dim=-1, keepdim=True)
        d = c / length
        scale = 2 * self.tan_half / self.height
        dc_dx, dc_dy = scale * r, -scale * u

        def normalised_derivative(dc):
            return (dc - d * (d * dc).sum(-1, keepdim=True)) / length

        n = pixels.shape[0]
        o = self._vec(self.origin, pixels).expand(n, 3)
        zero = torch.zeros_like(d)
        return Rays(o, d, zero, zero, normalised_derivative(dc_dx), normalised_derivative(dc_dy))


def make_camera(kind: str, width: int, height: int, origin, target, up=(0.0, 1.0, 0.0), fov: float = 30.0,
                half_height: float = 1.0) -> Camera:
    """"orthographic" (uses half_height) or "pinhole" (uses fov)."""
    if kind in ("orthographic", "ortho"):
        return OrthographicCamera(width, height, origin, target, up, half_height=half_height)
    if kind in ("pinhole", "perspective"):
        return PinholeCamera(width, height, origin, target, up, fov=fov)
    raise InputError(f"camera: expected 'orthographic' or 'pinhole', got {kind!r}")
