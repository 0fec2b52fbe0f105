"""Scenes: sphere and plane geometry and frames, the footprint against finite differences of uv, spec
errors, and the Mitsuba-backed mesh scene."""
import math

import pytest
import torch

from mitsuba_util import mitsuba_or_skip
from neumat import InputError, UnknownNameError
from neumat.render.scenes import PlaneScene, SphereScene, make_scene


def _pixel_grid(w, h, dtype=torch.float64):
    ys, xs = torch.meshgrid(torch.arange(h, dtype=dtype) + 0.5, torch.arange(w, dtype=dtype) + 0.5, indexing="ij")
    return torch.stack([xs.reshape(-1), ys.reshape(-1)], -1)


def _frame_checks(h):
    eye = torch.eye(3, dtype=h.n.dtype)
    frame = torch.stack([h.tangent, h.bitangent, h.n], 1)
    torch.testing.assert_close(frame @ frame.transpose(1, 2), eye.expand(len(h.n), 3, 3), atol=1e-6, rtol=0)
    torch.testing.assert_close(torch.linalg.cross(h.tangent, h.bitangent, dim=-1), h.n, atol=1e-6, rtol=0)


@pytest.mark.parametrize("camera", ["orthographic", "pinhole"])
def test_sphere_hits_lie_on_the_unit_sphere(camera):
    scene = SphereScene(32, 32, camera=camera)
    rays = scene.camera.rays(_pixel_grid(32, 32))
    h = scene.intersect(rays)
    torch.testing.assert_close(h.p.norm(dim=-1), torch.ones(len(h.p), dtype=torch.float64))
    torch.testing.assert_close(h.n, h.p)
    torch.testing.assert_close(rays.o[h.mask] + h.t[:, None] * rays.d[h.mask], h.p)
    assert ((h.n * rays.d[h.mask]).sum(-1) < 0).all()
    _frame_checks(h)
    # the sphere just fills the view: pixel centres inside the inscribed disk hit, corners miss
    px = _pixel_grid(32, 32)
    r = ((px - 16) / 16).norm(dim=-1)
    if camera == "orthographic":
        assert torch.equal(h.mask, r <= 1)
    assert not h.mask[r > 1.01].any() and h.mask[r < 0.95].all()


def test_sphere_tangent_follows_longitude_and_uv():
    scene = SphereScene(9, 9)
    h = scene.intersect(scene.camera.rays(torch.tensor([[4.5, 4.5], [7.5, 4.5]], dtype=torch.float64)))
    torch.testing.assert_close(h.tangent[0], torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64))
    torch.testing.assert_close(h.bitangent[0], torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64))
    x, y, z = h.p[1]
    torch.testing.assert_close(h.tangent[1], torch.stack([z, 0 * z, -x]) / torch.hypot(x, z))
    torch.testing.assert_close(h.uv[0], torch.tensor([0.0, 0.5], dtype=torch.float64))


def _fd_jacobian(scene, px, h=1e-3, unwrapped=None):
    """d uv / d pixel by central differences of uv (unwrapped(hits) -> uv, or the wrapped uv, unwrapped
    across the seam)."""
    def uv(x):
        hits = scene.intersect(scene.camera.rays(x))
        return hits.uv if unwrapped is None else unwrapped(hits)

    cols = []
    for axis in range(2):
        step = torch.zeros(2, dtype=px.dtype)
        step[axis] = h
        diff = uv(px + step) - uv(px - step)
        cols.append(diff if unwrapped is not None else torch.remainder(diff + 0.5, 1.0) - 0.5)
    return torch.stack(cols, -1) / (2 * h)


@pytest.mark.parametrize("opts", [dict(), dict(tilt=80.0, uv_scale=7.0), dict(tilt=20.0, distance=10.0, fov=10.0),
                                  dict(camera="orthographic", tilt=50.0)])
def test_plane_footprint_matches_finite_difference_jacobian(opts):
    scene = PlaneScene(48, 36, **opts)
    px = _pixel_grid(48, 36)
    hits = scene.intersect(scene.camera.rays(px))
    px = px[hits.mask]
    keep = scene.intersect(scene.camera.rays(px + 1e-3)).mask & scene.intersect(scene.camera.rays(px - 1e-3)).mask
    px = px[keep]
    jac = _fd_jacobian(scene, px, unwrapped=lambda hits: scene.surface_uv(hits.p))
    fp = scene.intersect(scene.camera.rays(px)).footprint
    torch.testing.assert_close(fp, jac @ jac.transpose(1, 2) / 12, rtol=1e-4, atol=0)
    # the footprint really spans scales across the image (for the tilted views)
    size = torch.linalg.det(fp).sqrt()
    if opts.get("tilt", 65) >= 65:
        assert size.max() / size.min() > 50


def test_plane_uv_and_frame():
    scene = PlaneScene(16, 16, uv_scale=3.0)
    h = scene.intersect(scene.camera.rays(_pixel_grid(16, 16)))
    torch.testing.assert_close(h.p[:, 1], torch.zeros(len(h.p), dtype=torch.float64), atol=1e-9, rtol=0)
    assert (h.uv >= 0).all() and (h.uv < 1).all()
    raw = torch.stack([h.p[:, 0], -h.p[:, 2]], -1) * 3
    torch.testing.assert_close(h.uv, torch.remainder(raw, 1.0))
    _frame_checks(h)


def test_sphere_footprint_matches_finite_differences_away_from_the_seam():
    scene = SphereScene(40, 40, camera="pinhole")
    px = _pixel_grid(40, 40)
    r = ((px - 20) / 20).norm(dim=-1)
    px = px[(r < 0.8) & ((px[:, 0] - 20).abs() > 1)]
    jac = _fd_jacobian(scene, px, h=1e-4)
    fp = scene.intersect(scene.camera.rays(px)).footprint
    torch.testing.assert_close(fp, jac @ jac.transpose(1, 2) / 12, rtol=1e-3, atol=1e-12)


def test_make_scene_specs_and_errors():
    s = make_scene("plane,tilt=30", (8, 8), uv_scale=2.0)
    assert isinstance(s, PlaneScene) and s.uv_scale == 2.0
    assert isinstance(make_scene("sphere,camera=pinhole,fov=20", (8, 8)), SphereScene)
    with pytest.raises(UnknownNameError, match="sphere, plane, mesh:PATH"):
        make_scene("spere", (8, 8))
    with pytest.raises(InputError, match="unknown option.*tilt"):
        make_scene("sphere", (8, 8), tilt=3)
    with pytest.raises(InputError, match="mesh:PATH"):
        make_scene("mesh", (8, 8))
    with pytest.raises(InputError, match="KEY=VALUE"):
        make_scene("sphere,pinhole", (8, 8))
    with pytest.raises(InputError, match="tilt"):
        make_scene("plane", (8, 8), tilt=95.0)
    with pytest.raises(InputError, match="orthographic"):
        make_scene("sphere", (8, 8), camera="fish")


@pytest.mark.mitsuba
def test_mesh_scene_intersects_and_tests_visibility(shared_data):
    mitsuba_or_skip()
    scene = make_scene(f"mesh:{shared_data / 'mesh' / 'stanford_bunny_res4_453v.ply'}", (24, 24))
    rays = scene.camera.rays(_pixel_grid(24, 24, torch.float32))
    h = scene.intersect(rays)
    assert 50 < int(h.mask.sum()) < 24 * 24
    assert h.uv is None and h.footprint is None  # the PLY has no texture coordinates
    torch.testing.assert_close(rays.o[h.mask] + h.t[:, None] * rays.d[h.mask], h.p, atol=1e-5, rtol=1e-5)
    assert ((h.ng * rays.d[h.mask]).sum(-1) <= 0).all()  # two-sided: normals face the camera
    _frame_checks(h)
    # a shadow ray along a camera ray is blocked exactly where the camera ray hits; back to the camera it is free
    d = rays.d
    blocked = scene.occluded(rays.o, -d, d, torch.full((len(d),), math.inf))
    assert torch.equal(blocked, h.mask)
    back = scene.occluded(h.p, h.ng, -rays.d[h.mask], h.t)
    assert back.float().mean() < 0.02


@pytest.mark.mitsuba
def test_mesh_scene_bad_files(tmp_path):
    mitsuba_or_skip()
    with pytest.raises(InputError, match="does not exist"):
        make_scene(f"mesh:{tmp_path / 'none.ply'}", (8, 8))
    bad = tmp_path / "bad.ply"
    bad.write_bytes(b"ply\nformat nonsense\n")
    with pytest.raises(InputError, match="bad.ply"):
        make_scene(f"mesh:{bad}", (8, 8))


def test_sphere_pole_has_a_finite_frame_and_footprint():
    scene = SphereScene(8, 8)
    h = scene.intersect(scene.camera.rays(torch.tensor([[4.0, 0.0]])))  # grazes the pole (0, 1, 0)
    assert h.mask.all()
    torch.testing.assert_close(h.n, torch.tensor([[0.0, 1.0, 0.0]]))
    assert torch.isfinite(h.footprint).all() and torch.isfinite(h.tangent).all()
    _frame_checks(h)
