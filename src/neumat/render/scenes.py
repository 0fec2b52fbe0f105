"""Scenes: what a camera ray hits and the shading data there (frame, uv, texture-space footprint).

World space is y-up; texture coordinates have v pointing up (textures appear upright). Scenes:
  sphere      unit sphere at the origin seen from +z (orthographic by default: the BRDF comparison view).
  plane       the textured plane y = 0 seen by a pinhole camera tilted from its normal.
  mesh:PATH   a PLY triangle mesh, intersected by Mitsuba 3 (llvm_ad_rgb variant).

Footprint: with J = d(u, v) / d(pixel x, pixel y) from ray differentials on the tangent plane, and a box
pixel filter (uniform over the 1 x 1 pixel, covariance I / 12 in pixel units), the footprint is the
covariance of that filter mapped to texture space: Sigma = J J^T / 12 (uv units^2). A Gaussian pixel
filter of standard deviation s pixels would give s^2 J J^T instead.
"""
from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from ..core.errors import DataFormatError, InputError
from ..core.frames import frame_from_normal, frame_from_normal_tangent
from ..core.mitsuba import import_mitsuba
from ..io.ply import check_ply
from .camera import Camera, Rays, make_camera
from .spec import as_float, check_options, parse_spec, unknown_name

SCENE_FORMS = ["sphere", "plane", "mesh:PATH"]
#: variance of a box pixel filter of width 1 along each axis
BOX_FILTER_VARIANCE = 1.0 / 12.0


@dataclass
class Hits:
    """Shading data of the rays that hit, for a batch of B rays of which M hit.

    mask: (B,) bool; the other tensors hold the M hits in order. t: (M,) ray distance; p: (M, 3) position;
    ng: (M, 3) geometric normal facing the ray's origin; n, tangent, bitangent: (M, 3) right-handed shading
    frame; uv: (M, 2) in [0, 1) or None; footprint: (M, 2, 2) Sigma (uv units^2) or None.
    """

    mask: torch.Tensor
    t: torch.Tensor
    p: torch.Tensor
    ng: torch.Tensor
    n: torch.Tensor
    tangent: torch.Tensor
    bitangent: torch.Tensor
    uv: torch.Tensor | None = None
    footprint: torch.Tensor | None = None


def uv_jacobian(rays: Rays, t: torch.Tensor, ng: torch.Tensor, dp_du: torch.Tensor,
                dp_dv: torch.Tensor) -> torch.Tensor:
    """J = d(u, v) / d(pixel x, y), (M, 2, 2), from ray differentials on the tangent plane (Igehy 1999).

    rays: the M rays that hit; t (M,) distances; ng (M, 3) normals; dp_du, dp_dv (M, 3) surface tangents.
    """
    cos = (ng * rays.d).sum(-1, keepdim=True)
    cos = torch.where(cos.abs() < 1e-12, torch.full_like(cos, -1e-12), cos)
    a = torch.stack([dp_du, dp_dv], -1)  # (M, 3, 2)
    gram = a.transpose(1, 2) @ a
    # a tiny ridge keeps degenerate parameterisations (poles, collapsed uv) finite instead of NaN
    ridge = 1e-7 * gram.diagonal(dim1=1, dim2=2).sum(-1) + 1e-30
    gram_inv = torch.linalg.inv(gram + ridge[:, None, None] * torch.eye(2, dtype=a.dtype, device=a.device))
    cols = []
    for do, dd in ((rays.do_dx, rays.dd_dx), (rays.do_dy, rays.dd_dy)):
        dp = do + t[:, None] * dd
        dp = dp - rays.d * (ng * dp).sum(-1, keepdim=True) / cos  # stay on the tangent plane
        cols.append((gram_inv @ (a.transpose(1, 2) @ dp.unsqueeze(-1))).squeeze(-1))
    return torch.stack(cols, -1)


def footprint_from_jacobian(jac: torch.Tensor) -> torch.Tensor:
    """Sigma = J J^T / 12 (M, 2, 2): the box pixel filter's covariance in texture space."""
    return BOX_FILTER_VARIANCE * jac @ jac.transpose(1, 2)


class Scene(ABC):
    """Base class: a camera, ray intersection and (for non-convex scenes) shadow-ray tests."""

    #: whether shading points can be shadowed (the integrator then traces shadow rays)
    needs_visibility = False
    camera: Camera

    @abstractmethod
    def intersect(self, rays: Rays, with_uv: bool = True) -> Hits:
        """Hits of a batch of rays; uv and footprint are left None when `with_uv` is False."""

    def occluded(self, p: torch.Tensor, ng: torch.Tensor, wi: torch.Tensor, dist: torch.Tensor) -> torch.Tensor:
        """(M,) True where the segment from p (M, 3) along wi (M, 3) up to dist (M,) is blocked."""
        return torch.zeros(p.shape[0], dtype=torch.bool, device=p.device)


class SphereScene(Scene):
    """Unit sphere at the origin, camera on +z. uv = (phi / 2 pi, 1 - theta / pi) with theta from +y and
    phi = atan2(x, z) (v points up, as in `neumat.nn.latent_texture`); the tangent follows d p / d phi
    (the +x direction at the front), so anisotropic materials show a consistent orientation."""

    OPTIONS = {"camera": "orthographic (default) or pinhole",
               "fov": "pinhole vertical field of view in degrees (default 30)",
               "distance": "camera distance from the centre (default: the sphere just fills the view)",
               "margin": "extra space around the sphere, fraction of its radius (default 0)"}

    def __init__(self, width: int, height: int, camera: str = "orthographic", fov: float = 30.0,
                 distance: float | None = None, margin: float = 0.0) -> None:
        fov, margin = as_float(fov, "sphere scene: fov"), as_float(margin, "sphere scene: margin")
        if margin < 0:
            raise InputError(f"sphere scene: margin must be >= 0, got {margin}")
        extent = 1.0 + margin
        if distance is None:
            distance = extent / math.sin(math.radians(fov) / 2) if camera == "pinhole" else 5.0
        distance = as_float(distance, "sphere scene: distance")
        if distance <= 1:
            raise InputError(f"sphere scene: the camera must be outside the sphere (distance > 1), got {distance}")
        self.camera = make_camera(camera, width, height, (0.0, 0.0, distance), (0.0, 0.0, 0.0), fov=fov,
                                  half_height=extent)

    def intersect(self, rays: Rays, with_uv: bool = True) -> Hits:
        b = (rays.o * rays.d).sum(-1)
        c = (rays.o * rays.o).sum(-1) - 1
        disc = b * b - c
        t_all = -b - disc.clamp(min=0).sqrt()
        mask = (disc >= 0) & (t_all > 0)
        t = t_all[mask]
        p = rays.o[mask] + t[:, None] * rays.d[mask]
        n = p / p.norm(dim=-1, keepdim=True)
        x, y, z = n.unbind(-1)
        dp_du = 2 * math.pi * torch.stack([z, torch.zeros_like(z), -x], -1)
        tangent, bitangent = frame_from_normal_tangent(n, _fallback_tangent(dp_du))
        if not with_uv:
            return Hits(mask, t, p, n, n, tangent, bitangent)
        sin_theta = (x * x + z * z).sqrt().clamp(min=1e-6)
        dp_dv = -math.pi * torch.stack([x * y / sin_theta, -sin_theta, z * y / sin_theta], -1)  # -pi dp/dtheta
        u = torch.remainder(torch.atan2(x, z) / (2 * math.pi), 1.0)
        v = 1 - torch.acos(y.clamp(-1, 1)) / math.pi
        jac = uv_jacobian(rays[mask], t, n, dp_du, dp_dv)
        return Hits(mask, t, p, n, n, tangent, bitangent, torch.stack([u, v], -1), footprint_from_jacobian(jac))


class PlaneScene(Scene):
    """The infinite plane y = 0 (normal +y, tangent +x, bitangent -z), textured with
    uv = fract((x, -z) * uv_scale), seen by a camera at `distance` from the origin, `tilt` degrees from
    the normal, looking at the origin. Tilts near 90 degrees reach the horizon, so footprints span many
    scales; larger uv_scale shrinks the texture (more repeats, larger footprints)."""

    OPTIONS = {"tilt": "camera angle from the plane normal in degrees (default 65)",
               "distance": "camera distance from the origin (default 3)",
               "fov": "vertical field of view in degrees (default 40)",
               "uv_scale": "texture repeats per world unit (default 1)",
               "camera": "pinhole (default) or orthographic (half height = distance tan(fov / 2))"}

    def __init__(self, width: int, height: int, tilt: float = 65.0, distance: float = 3.0, fov: float = 40.0,
                 uv_scale: float = 1.0, camera: str = "pinhole") -> None:
        tilt, distance = as_float(tilt, "plane scene: tilt"), as_float(distance, "plane scene: distance")
        fov, uv_scale = as_float(fov, "plane scene: fov"), as_float(uv_scale, "plane scene: uv_scale")
        if not 0 <= tilt < 90:
            raise InputError(f"plane scene: tilt must lie in [0, 90) degrees, got {tilt}")
        if distance <= 0 or uv_scale <= 0:
            raise InputError(f"plane scene: distance and uv_scale must be > 0, got {distance}, {uv_scale}")
        a = math.radians(tilt)
        origin = (0.0, distance * math.cos(a), distance * math.sin(a))
        up = (0.0, math.sin(a), -math.cos(a))
        self.camera = make_camera(camera, width, height, origin, (0.0, 0.0, 0.0), up, fov=fov,
                                  half_height=distance * math.tan(math.radians(fov) / 2))
        self.uv_scale = uv_scale

    def surface_uv(self, p: torch.Tensor) -> torch.Tensor:
        """Unwrapped texture coordinates (M, 2) of points p (M, 3) on the plane."""
        return torch.stack([p[:, 0], -p[:, 2]], -1) * self.uv_scale

    def intersect(self, rays: Rays, with_uv: bool = True) -> Hits:
        dy = rays.d[:, 1]
        t_all = -rays.o[:, 1] / torch.where(dy < 0, dy, -torch.ones_like(dy))
        mask = (dy < 0) & (t_all > 0) & torch.isfinite(t_all)
        t = t_all[mask]
        p = rays.o[mask] + t[:, None] * rays.d[mask]
        m = p.shape[0]
        n = p.new_tensor([0.0, 1.0, 0.0]).expand(m, 3)
        tangent = p.new_tensor([1.0, 0.0, 0.0]).expand(m, 3)
        bitangent = p.new_tensor([0.0, 0.0, -1.0]).expand(m, 3)
        if not with_uv:
            return Hits(mask, t, p, n, n, tangent, bitangent)
        jac = uv_jacobian(rays[mask], t, n, tangent / self.uv_scale, bitangent / self.uv_scale)
        uv = torch.remainder(self.surface_uv(p), 1.0)
        return Hits(mask, t, p, n, n, tangent, bitangent, uv, footprint_from_jacobian(jac))


class MeshScene(Scene):
    """A PLY triangle mesh intersected by Mitsuba 3; the pinhole camera frames its bounding sphere from
    the direction (azimuth, elevation) (degrees; azimuth 0 is +z, elevation 0 the horizon). Surfaces are
    two-sided. uv and footprint come from the mesh's texture coordinates and are None when it has none."""

    needs_visibility = True
    OPTIONS = {"fov": "vertical field of view in degrees (default 30)",
               "azimuth": "camera azimuth in degrees around +y, 0 = from +z (default 0)",
               "elevation": "camera elevation in degrees (default 15)",
               "zoom": "scale of the framed bounding sphere in the view (default 1)"}

    def __init__(self, path: str, width: int, height: int, fov: float = 30.0, azimuth: float = 0.0,
                 elevation: float = 15.0, zoom: float = 1.0) -> None:
        fov, zoom = as_float(fov, "mesh scene: fov"), as_float(zoom, "mesh scene: zoom")
        azimuth, elevation = as_float(azimuth, "mesh scene: azimuth"), as_float(elevation, "mesh scene: elevation")
        if zoom <= 0:
            raise InputError(f"mesh scene: zoom must be > 0, got {zoom}")
        path = Path(path)
        if not path.is_file():
            raise InputError(f"mesh scene: PLY file {path} does not exist")
        if path.suffix.lower() != ".ply":
            raise InputError(f"mesh scene: expected a .ply triangle mesh, got {path}")
        check_ply(path)
        self.mi = import_mitsuba()
        try:
            self.scene = self.mi.load_dict({"type": "scene", "mesh": {"type": "ply", "filename": str(path)}})
        except Exception as e:  # Mitsuba raises RuntimeError with the parser's message
            raise DataFormatError(f"mesh scene: could not read {path} as a PLY mesh: {e}") from e
        self.has_uv = bool(self.scene.shapes()[0].has_vertex_texcoords())
        box = self.scene.bbox()
        lo, hi = np.array(box.min, dtype=np.float64), np.array(box.max, dtype=np.float64)
        centre, radius = (lo + hi) / 2, float(np.linalg.norm(hi - lo)) / 2
        if not radius > 0:
            raise DataFormatError(f"mesh scene: {path} has an empty or degenerate bounding box")
        self.radius = radius
        a, e = math.radians(azimuth), math.radians(elevation)
        direction = np.array([math.cos(e) * math.sin(a), math.sin(e), math.cos(e) * math.cos(a)])
        distance = radius / zoom / math.sin(math.radians(fov) / 2)
        up = (0.0, 1.0, 0.0) if abs(direction[1]) < 0.999 else (0.0, 0.0, -1.0)
        self.camera = make_camera("pinhole", width, height, tuple(centre + distance * direction), tuple(centre),
                                  up, fov=fov)

    def _ray(self, o: torch.Tensor, d: torch.Tensor, maxt: torch.Tensor | None = None):
        mi = self.mi
        ray = mi.Ray3f(mi.Point3f(_to_np(o)), mi.Vector3f(_to_np(d)))
        return ray if maxt is None else mi.Ray3f(ray, mi.Float(maxt.detach().cpu().numpy().astype(np.float32)))

    def intersect(self, rays: Rays, with_uv: bool = True) -> Hits:
        like = rays.d
        si = self.scene.ray_intersect(self._ray(rays.o, rays.d))
        mask = _from_np(si.is_valid(), like.device, torch.bool)
        r = rays[mask]

        def field(v):
            return _from_np(v, like.device, like.dtype)[mask]

        t, p, ng, n = field(si.t), field(si.p), field(si.n), field(si.sh_frame.n)
        flip = torch.where((ng * r.d).sum(-1, keepdim=True) > 0, -1.0, 1.0).to(like.dtype)
        ng, n = ng * flip, n * flip
        n = n / n.norm(dim=-1, keepdim=True).clamp(min=1e-12)
        uv = footprint = None
        if self.has_uv and with_uv:
            dp_du, dp_dv = field(si.dp_du), field(si.dp_dv)
            tangent, bitangent = frame_from_normal_tangent(n, _fallback_tangent(dp_du))
            uv = torch.remainder(field(si.uv), 1.0)
            footprint = footprint_from_jacobian(uv_jacobian(r, t, ng, dp_du, dp_dv))
        else:
            tangent, bitangent = frame_from_normal(n)
        return Hits(mask, t, p, ng, n, tangent, bitangent, uv, footprint)

    def occluded(self, p: torch.Tensor, ng: torch.Tensor, wi: torch.Tensor, dist: torch.Tensor) -> torch.Tensor:
        if p.shape[0] == 0:
            return torch.zeros(0, dtype=torch.bool, device=p.device)
        eps = 1e-4 * self.radius
        side = torch.where((ng * wi).sum(-1, keepdim=True) >= 0, 1.0, -1.0).to(p.dtype)
        origin = p + eps * side * ng
        maxt = torch.where(torch.isfinite(dist), dist * (1 - 1e-4) - eps, torch.full_like(dist, float("inf")))
        blocked = self.scene.ray_test(self._ray(origin, wi, maxt))
        return _from_np(blocked, p.device, torch.bool)


def make_scene(spec: str, resolution: tuple[int, int], **options) -> Scene:
    """Build a scene from a spec string (see the module docstring) at resolution (width, height).

    Keyword options override those written in the spec (`"plane,tilt=80"` or `tilt=80`)."""
    s = parse_spec(spec, "scene")
    opts = {**s.options, **options}
    width, height = resolution
    builders = {"sphere": SphereScene, "plane": PlaneScene, "mesh": MeshScene}
    if s.name not in builders:
        raise unknown_name("scene", s.name, SCENE_FORMS)
    cls = builders[s.name]
    check_options(opts, cls.OPTIONS, f"scene {spec!r}")
    if s.name == "mesh":
        if not s.arg:
            raise InputError(f"scene {spec!r}: expected mesh:PATH with the path of a PLY file")
        return cls(s.arg, width, height, **opts)
    if s.arg is not None:
        raise InputError(f"scene {spec!r}: {s.name} takes no ':' argument (options go after ',')")
    return cls(width, height, **opts)


def _fallback_tangent(dp_du: torch.Tensor) -> torch.Tensor:
    """dp_du where it is usable, +x where it vanishes (poles, degenerate uv)."""
    ok = dp_du.norm(dim=-1, keepdim=True) > 1e-8
    return torch.where(ok, dp_du, dp_du.new_tensor([1.0, 0.0, 0.0]).expand_as(dp_du))


def _to_np(x: torch.Tensor) -> np.ndarray:
    """(N, 3) torch -> (3, N) float32 numpy for Mitsuba."""
    return np.ascontiguousarray(x.detach().cpu().numpy().astype(np.float32).T)


def _from_np(v, device, dtype) -> torch.Tensor:
    """A Dr.Jit array ((N,) or (3, N)) -> torch (N,) or (N, 3)."""
    arr = np.array(v)
    if arr.ndim == 2:
        arr = arr.T
    return torch.from_numpy(np.ascontiguousarray(arr)).to(device=device, dtype=dtype)
