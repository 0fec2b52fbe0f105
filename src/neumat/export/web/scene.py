"""The web viewer's scene in torch: the queries of every pixel and the image a material gives there.

The page (`viewer.html`) and `viewer_image` compute the same thing. Pixel (column i, row j counted from the
bottom) sits at p = 1.25 (2 (i + 1/2, j + 1/2) - (W, H)) / min(W, H) in view space; the camera is orthographic
along -z, so the viewer direction is +z. The object is rotated by R = Rx(pitch) Ry(yaw) (object -> view):

- sphere: the unit sphere; normal n = (p, sqrt(1 - |p|^2)); with m = R^T n, uv = (atan2(m_y, m_x) / 2 pi + 1/2,
  atan2(m_z, |m_xy|) / pi + 1/2) x (2, 1) x tiles, tangent along increasing azimuth;
- plane: the square |x|, |y| < 0.8 of the object's xy plane, normal R e_z, uv = (xy / 1.6 + 1/2) x tiles,
  tangent R e_x (hidden when R e_z faces away: n_z <= 1e-3).

Details: docs/formats/web_viewer.md, section `neumat.export.web.scene`.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import torch

from ...core.errors import InputError
from ...core.query import Query

SHAPES = ("sphere", "plane")


@dataclass
class View:
    """A viewer view; angles in radians. The page's defaults."""

    yaw: float = 0.4
    pitch: float = -0.9
    azimuth: float = 0.8
    elevation: float = 0.9
    exposure: float = 0.0
    """log2 of the light's radiance."""
    tiles: float = 1.0
    shape: str = "sphere"

    def page_state(self) -> dict:
        """The view as the page's `view` object (shape as its index)."""
        if self.shape not in SHAPES:
            raise InputError(f"View.shape: expected one of {SHAPES}, got {self.shape!r}")
        return {**asdict(self), "shape": SHAPES.index(self.shape)}


def rotation(yaw: float, pitch: float) -> torch.Tensor:
    """R = Rx(pitch) Ry(yaw), (3, 3) float64, object -> view."""
    cy, sy, cp, sp = math.cos(yaw), math.sin(yaw), math.cos(pitch), math.sin(pitch)
    return torch.tensor([[cy, 0.0, sy], [sp * sy, cp, -sp * cy], [-cp * sy, sp, cp * cy]], dtype=torch.float64)


def viewer_queries(view: View, width: int, height: int) -> tuple[Query, torch.Tensor]:
    """(queries (H W,) in float32 with uv, mask (H W,) of pixels on the object and above both horizons), pixels
    in row-major order from the top row down; directions of masked-out pixels are +z."""
    if view.shape not in SHAPES:
        raise InputError(f"View.shape: expected one of {SHAPES}, got {view.shape!r}")
    if width < 1 or height < 1:
        raise InputError(f"viewer_queries: expected a positive size, got {width} x {height}")
    d = torch.float64
    rows = torch.arange(height - 1, -1, -1, dtype=d) + 0.5  # top row first
    cols = torch.arange(width, dtype=d) + 0.5
    y, x = torch.meshgrid(rows, cols, indexing="ij")
    p = 1.25 * torch.stack([2 * x - width, 2 * y - height], -1).reshape(-1, 2) / min(width, height)
    r = rotation(view.yaw, view.pitch)
    if view.shape == "sphere":
        r2 = (p * p).sum(-1)
        hit = r2 < 1
        n = torch.cat([p, (1 - r2).clamp(min=0).sqrt().unsqueeze(-1)], -1)
        m = n @ r  # R^T n, row vectors
        rxy = m[:, :2].norm(dim=-1)
        uv = torch.stack([torch.atan2(m[:, 1], m[:, 0]) / (2 * math.pi) + 0.5,
                          torch.atan2(m[:, 2], rxy) / math.pi + 0.5], -1) * torch.tensor([2.0, 1.0], dtype=d)
        pole = rxy <= 1e-6
        tangent = torch.stack([-m[:, 1], m[:, 0], torch.zeros_like(rxy)], -1) / rxy.clamp(min=1e-300).unsqueeze(-1)
        tangent[pole] = torch.tensor([1.0, 0.0, 0.0], dtype=d)
        t = tangent @ r.t()
    else:
        normal = r[:, 2]
        n = normal.expand(len(p), 3)
        facing = float(normal[2]) > 1e-3
        z = -(p[:, 0] * normal[0] + p[:, 1] * normal[1]) / (normal[2] if facing else 1.0)
        o = torch.cat([p, z.unsqueeze(-1)], -1) @ r
        hit = (o[:, :2].abs().amax(-1) < 0.8) & facing
        uv = o[:, :2] / 1.6 + 0.5
        t = r[:, 0].expand(len(p), 3)
    uv = uv * view.tiles
    b = torch.cross(n, t, dim=-1)
    light = torch.tensor([math.cos(view.elevation) * math.cos(view.azimuth),
                          math.cos(view.elevation) * math.sin(view.azimuth), math.sin(view.elevation)], dtype=d)
    wi = torch.stack([t @ light, b @ light, n @ light], -1)
    wo = torch.stack([t[:, 2], b[:, 2], n[:, 2]], -1)
    valid = hit & (wi[:, 2] > 0) & (wo[:, 2] > 0)
    up = torch.tensor([0.0, 0.0, 1.0], dtype=d)
    wi, wo = (torch.where(valid.unsqueeze(-1), w, up) for w in (wi, wo))  # off the object: any unit vector
    return Query(wi=wi.float(), wo=wo.float(), uv=uv.float()), valid


def viewer_image(material, view: View, width: int, height: int) -> torch.Tensor:
    """Linear RGB image (H, W, 3) float32 of `material` (anything with `eval(Query)`) in the viewer's scene,
    top row first; footprint-free queries (module docstring)."""
    q, valid = viewer_queries(view, width, height)
    out = torch.zeros(width * height, 3)
    idx = valid.nonzero().squeeze(-1)
    if len(idx):
        sub = Query(wi=q.wi[idx], wo=q.wo[idx], uv=q.uv[idx])
        with torch.no_grad():
            f = material.eval(sub).float().cpu()
        out[idx] = f * sub.wi[:, 2:3] * 2.0 ** view.exposure
    return out.view(height, width, 3)
