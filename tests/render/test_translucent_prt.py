"""Images from an SH PRT table: the barycentric render of a table whose transport is constant per vertex is the
analytic image (a linear function of the hit point on a quad, exact at every jittered sample)."""
import math

import numpy as np
import pytest
import torch

from neumat import InputError
from neumat.methods.neupress.prt import PRTConfig, SHPRT
from neumat.render.camera import make_camera
from neumat.render.lights import EnvironmentMap
from neumat.render.translucent import _pixel_rays
from neumat.render.translucent_prt import render_prt
from tests.mitsuba_util import mitsuba_or_skip

H = 0.8  # half side of the quad


def _f(p):
    """The per-vertex radiance: linear in position, so its barycentric interpolation is exact."""
    base = 1 + 0.3 * p[:, 0] + 0.2 * p[:, 1]
    return base[:, None] * torch.tensor([1.0, 0.5, 2.0], dtype=p.dtype)


@pytest.mark.mitsuba
def test_constant_per_vertex_transport_gives_the_analytic_image():
    mitsuba_or_skip()
    points = torch.tensor([[-H, -H, 0.0], [H, -H, 0], [H, H, 0], [-H, H, 0]])
    normals = torch.tensor([[0.0, 0, 1]]).expand(4, 3)
    faces = torch.tensor([[0, 1, 2], [0, 2, 3]])
    cfg = PRTConfig(degree=1, view_theta=2, view_phi=3)
    coeffs = torch.zeros(4, 2, 3, 4, 3)
    coeffs[:, :, :, 0] = (_f(points) / math.sqrt(4 * math.pi))[:, None, None]  # a_00, the same in every view bin
    prt = SHPRT(coeffs, points, normals, cfg, faces=faces)
    c = np.array([0.5, 1.0, 1.5], dtype=np.float32)
    env = EnvironmentMap(np.broadcast_to(c, (4, 8, 3)).copy())  # b_00 = c sqrt(4 pi)
    res, spp = 12, 3
    camera = make_camera("pinhole", res, res, (0.2, 0.1, 4.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), fov=30.0)
    image = render_prt(prt, env, camera, res, spp=spp, seed=7)

    o, d = _pixel_rays(camera, res, spp, torch.Generator().manual_seed(7))  # the same samples
    p = o - (o[:, 2:] / d[:, 2:]) * d  # on the plane z = 0
    inside = (p[:, :2].abs() < H).all(-1, keepdim=True)
    expected = torch.where(inside, _f(p) * torch.from_numpy(c).double(), torch.zeros(1, dtype=torch.float64))
    expected = expected.reshape(res * res, spp, 3).mean(1).reshape(res, res, 3)
    assert 0 < float(inside.double().mean()) < 1  # the quad's edges cross the image
    torch.testing.assert_close(image.double(), expected, rtol=1e-4, atol=1e-4)

    with pytest.raises(InputError, match="faces"):
        render_prt(SHPRT(coeffs, points, normals, cfg), env, camera, res)
