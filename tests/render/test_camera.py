"""Cameras: ray directions and origins, and ray differentials against finite differences."""
import math

import pytest
import torch

from neumat import InputError
from neumat.render.camera import OrthographicCamera, PinholeCamera, make_camera


def _pixels(w, h, n=50, seed=0):
    g = torch.Generator().manual_seed(seed)
    return torch.rand(n, 2, generator=g, dtype=torch.float64) * torch.tensor([w, h], dtype=torch.float64)


@pytest.mark.parametrize("kind", ["orthographic", "pinhole"])
def test_differentials_match_finite_differences(kind):
    cam = make_camera(kind, 40, 30, (0.3, 1.0, 4.0), (0.0, 0.2, 0.0), fov=50, half_height=1.5)
    px = _pixels(40, 30)
    r = cam.rays(px)
    h = 1e-4
    for axis, (do, dd) in enumerate([(r.do_dx, r.dd_dx), (r.do_dy, r.dd_dy)]):
        step = torch.zeros(2, dtype=torch.float64)
        step[axis] = h
        a, b = cam.rays(px + step), cam.rays(px - step)
        torch.testing.assert_close(do, (a.o - b.o) / (2 * h), atol=1e-7, rtol=1e-6)
        torch.testing.assert_close(dd, (a.d - b.d) / (2 * h), atol=1e-7, rtol=1e-6)
    torch.testing.assert_close(r.d.norm(dim=-1), torch.ones(50, dtype=torch.float64))


def test_pinhole_field_of_view_and_orientation():
    cam = PinholeCamera(64, 32, (0.0, 0.0, 5.0), (0.0, 0.0, 0.0), fov=60)
    r = cam.rays(torch.tensor([[32.0, 16.0], [32.0, 0.0], [64.0, 16.0]]))
    torch.testing.assert_close(r.d[0], torch.tensor([0.0, 0.0, -1.0]))
    assert math.degrees(math.acos(-r.d[1, 2])) == pytest.approx(30, abs=1e-4)  # top edge: half the fov
    assert r.d[1, 1] > 0 and r.d[2, 0] > 0  # image top is +y, image right is +x
    assert r.d[2, 0] / -r.d[2, 2] == pytest.approx(2 * math.tan(math.radians(30)), rel=1e-5)  # aspect 2


def test_orthographic_spans_half_height():
    cam = OrthographicCamera(20, 10, (0.0, 0.0, 5.0), (0.0, 0.0, 0.0), half_height=2.0)
    r = cam.rays(torch.tensor([[0.0, 0.0], [20.0, 10.0]]))
    torch.testing.assert_close(r.o, torch.tensor([[-4.0, 2.0, 5.0], [4.0, -2.0, 5.0]]))
    torch.testing.assert_close(r.d, torch.tensor([[0.0, 0.0, -1.0]] * 2))


def test_bad_cameras():
    with pytest.raises(InputError, match="fov"):
        PinholeCamera(8, 8, (0, 0, 1), (0, 0, 0), fov=180)
    with pytest.raises(InputError, match="parallel"):
        PinholeCamera(8, 8, (0, 2, 0), (0, 0, 0), up=(0, 1, 0))
    with pytest.raises(InputError, match="coincide"):
        OrthographicCamera(8, 8, (0, 0, 0), (0, 0, 0))
    with pytest.raises(InputError, match="orthographic"):
        make_camera("fisheye", 8, 8, (0, 0, 1), (0, 0, 0))
    with pytest.raises(InputError, match="pixels"):
        PinholeCamera(8, 8, (0, 0, 1), (0, 0, 0)).rays(torch.zeros(4, 3))
