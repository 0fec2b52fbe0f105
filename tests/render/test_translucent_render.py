"""Rendering translucent objects under an environment: Eq. 5 estimators against closed forms, and the
path-traced reference against directional-light traces (the environment orientation agrees with Mitsuba)."""
import math

import numpy as np
import pytest
import torch

from neumat import InputError
from neumat.render.envmaps import equirect_to_dir
from neumat.render.lights import EnvironmentMap
from neumat.warp import azimuthal_gaussian_pdf, sample_azimuthal_gaussian
from tests.mitsuba_util import mitsuba_or_skip

pytestmark = pytest.mark.mitsuba


class _Constant:
    """S_hat = c everywhere, with a Gaussian light sampler of width 1 around the normal."""

    full_sphere = True

    def __init__(self, c):
        self.c = torch.tensor(c)

    def eval(self, q):
        return self.c.expand(len(q), 3).to(q.wi.dtype)

    def sample_incident(self, q, u):
        sigma = torch.ones(len(q))
        wi = sample_azimuthal_gaussian(u, q.n, sigma)
        return wi, azimuthal_gaussian_pdf(wi, q.n, sigma)


def _setup(resolution=8):
    mitsuba_or_skip()
    from neumat.reflectance.translucent import TranslucentObject
    from neumat.render.translucent import orbit_camera
    obj = TranslucentObject(spp=64)
    return obj, orbit_camera(obj, resolution, fov=20.0)


@pytest.mark.parametrize("strategy", ["light", "model"])
def test_constant_transport_integrates_the_environment(strategy):
    from neumat.render.translucent import render_translucent
    obj, camera = _setup()
    g = torch.Generator().manual_seed(0)
    image = 0.2 + torch.rand(8, 16, 3, generator=g)
    env = EnvironmentMap(image)
    rows = torch.cos(torch.arange(9) * math.pi / 8)
    solid = ((rows[:-1] - rows[1:]) * 2 * math.pi / 16)[:, None, None]
    c = (0.02, 0.05, 0.1)
    exact = torch.tensor(c) * (image * solid).sum((0, 1))
    img = render_translucent(_Constant(c), obj, env, camera, 8, spp=4096, strategy=strategy)
    centre = img[3:5, 3:5].reshape(-1, 3)  # the sphere fills the middle of the view
    assert torch.allclose(centre, exact.expand_as(centre), rtol=0.03), (centre, exact)
    assert torch.equal(img[0, 0], torch.zeros(3))  # corners miss the sphere: black background


def test_reference_under_a_one_texel_environment_matches_the_directional_trace():
    """An environment black but for one texel of radiance L and solid angle Omega lights like a directional
    light of irradiance L Omega from the texel's direction (up to the texel's 6-degree extent), along the
    same camera rays: the environment mapping agrees with Mitsuba's envmap."""
    from neumat.render.translucent import render_translucent_reference
    obj, camera = _setup(4)
    h, w = 32, 64
    image = np.zeros((h, w, 3), np.float32)
    for i, j in ((12, 40), (20, 10)):
        image[:] = 0
        image[i, j] = 1000.0
        omega = (math.cos(i * math.pi / h) - math.cos((i + 1) * math.pi / h)) * 2 * math.pi / w
        centre = equirect_to_dir(torch.tensor([[(j + 0.5) / w, (i + 0.5) / h]], dtype=torch.float64))[0]
        x = torch.nn.functional.normalize(torch.tensor([[0.1, 0.3, 1.0], [-0.4, 0.0, 1.0]], dtype=torch.float64),
                                          dim=-1)
        o, d = 3 * x, -x  # rays towards the centre of the unit sphere
        n = 1 << 16
        env = obj.trace_environment(o.repeat_interleave(n, 0), d.repeat_interleave(n, 0), image).reshape(2, n, 3)
        direct = obj.trace(o.repeat_interleave(n, 0), d.repeat_interleave(n, 0), centre, spp=1).reshape(2, n, 3)
        direct = direct * (1000.0 * omega)
        diff = env.mean(1) - direct.mean(1)
        se = ((env.var(1) + direct.var(1)) / n).sqrt()
        # 4 standard errors of Monte Carlo noise plus 5% for the texel's extent (the environment spreads the
        # light over 5.6 x 5.6 degrees; the directional light comes from its centre)
        assert bool((diff.abs() < 4 * se + 0.05 * direct.mean(1)).all()), (env.mean(1), direct.mean(1), se)
    ref = render_translucent_reference(obj, EnvironmentMap(image), camera, 4, spp=16)
    assert ref.shape == (4, 4, 3) and torch.equal(ref[0, 0], torch.zeros(3))


def test_bad_strategy_and_spp():
    from neumat.render.translucent import render_translucent
    obj, camera = _setup()
    env = EnvironmentMap(torch.ones(4, 8, 3))
    with pytest.raises(InputError, match="strategy"):
        render_translucent(_Constant((1, 1, 1)), obj, env, camera, 8, strategy="bsdf")
    with pytest.raises(InputError, match="spp"):
        render_translucent(_Constant((1, 1, 1)), obj, env, camera, 8, spp=0)
