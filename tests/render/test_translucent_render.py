"""Rendering translucent objects under an environment: Eq. 5 estimators against closed forms, and the
path-traced reference against directional-light traces (the environment orientation agrees with Mitsuba)."""
import math

import numpy as np
import pytest
import torch

from neumat import InputError
from neumat.render.envmaps import equirect_to_dir
from neumat.render.lights import EnvironmentMap
from neumat.warp import azimuthal_gaussian_pdf, sample_azimuthal_gaussian, sample_uniform_sphere
from neumat.warp.azimuthal_gaussian import AzimuthalGaussianLobe
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


class _Zero:
    """S_hat = 0: the full appearance is the surface reflection and the background alone."""

    full_sphere = True

    def eval(self, q):
        return torch.zeros(len(q), 3, dtype=q.wi.dtype)


class _Lobe:
    """A smooth S_hat peaked around the normal and tinted by position, with a Gaussian lobe sampler and its pdf."""

    full_sphere = True

    def eval(self, q):
        cos = (q.wi * q.n).sum(-1, keepdim=True)
        tint = torch.tensor([0.03, 0.05, 0.08], dtype=q.wi.dtype)
        return tint * torch.exp(3 * (cos - 1)) * (1 + 0.5 * q.x[:, :1])

    def sample_incident(self, q, u):
        sigma = torch.full((len(q),), 0.7, dtype=q.n.dtype)
        wi = sample_azimuthal_gaussian(u.to(q.n.dtype), q.n, sigma)
        return wi, azimuthal_gaussian_pdf(wi, q.n, sigma)

    def incident_pdf(self, q):
        return azimuthal_gaussian_pdf(q.wi, q.n, torch.full((len(q),), 0.7, dtype=q.n.dtype))


class _LobeOnce(_Lobe):
    """_Lobe through `incident_lobe` only: one lobe per batch for both sampling and densities."""

    def __init__(self):
        self.lobes = 0

    def incident_lobe(self, q):
        self.lobes += 1
        return AzimuthalGaussianLobe(q.n, torch.full((len(q),), 0.7, dtype=q.n.dtype))

    def sample_incident(self, q, u):
        raise AssertionError("mis with incident_lobe must not call sample_incident")

    def incident_pdf(self, q):
        raise AssertionError("mis with incident_lobe must not call incident_pdf")


class _Uniform(_Lobe):
    """The same S_hat sampled uniformly over the sphere: a brute-force estimator."""

    def sample_incident(self, q, u):
        wi = sample_uniform_sphere(u.to(q.n.dtype))
        return wi, torch.full((len(q),), 1 / (4 * math.pi), dtype=q.n.dtype)


def _smooth_environment(h=16, w=32):
    theta = ((torch.arange(h) + 0.5) / h * math.pi)[:, None].expand(h, w)
    phi = ((torch.arange(w) + 0.5) / w * 2 * math.pi)[None, :].expand(h, w)
    return EnvironmentMap(torch.stack([0.7 + 0.4 * torch.cos(theta) + 0.2 * torch.sin(phi),
                                       0.6 + 0.3 * torch.sin(phi) * torch.sin(theta),
                                       0.7 - 0.3 * torch.cos(theta)], -1))


def _agreement(a1, a2, b1, b2, mask=None):
    """How well renders a and b of the same image agree, given second renders a2, b2 (same settings, other seeds)
    that measure their noise: (sum (a1 - b1)^2 over its expectation, about 1 when they agree; the mean of
    a1 - b1; its standard error)."""
    sel = (lambda t: t[mask]) if mask is not None else (lambda t: t.reshape(-1, 3))
    variance = 0.5 * sel(a1 - a2) ** 2 + 0.5 * sel(b1 - b2) ** 2
    diff = sel(a1 - b1)
    return float((diff ** 2).sum() / variance.sum()), float(diff.mean()), float((variance.mean() / diff.numel()).sqrt())


def test_full_appearance_of_a_zero_model_is_the_reflection_reference():
    """With S_hat = 0 the full render (GGX reflection of the environment by MIS, the background) equals
    Mitsuba's trace with a black interior (reflection and background, nothing below the surface)."""
    from neumat.render.translucent import _pixel_rays, render_translucent, render_translucent_reference
    obj, camera = _setup(16)
    env = _smooth_environment()
    renders = [render_translucent(_Zero(), obj, env, camera, 16, spp=64, seed=s, appearance="full") for s in (1, 2)]
    refs = [render_translucent_reference(obj, env, camera, 16, spp=512, seed=s, appearance="reflection")
            for s in (3, 4)]
    ratio = _agreement(renders[0], renders[1], refs[0], refs[1])[0]
    assert ratio < 2, ratio
    o, d = _pixel_rays(camera, 16, 64, torch.Generator().manual_seed(1))
    inside = obj.first_hits(o, d)[0].reshape(16, 16, 64).all(-1)  # pixels the object covers
    _, diff, se = _agreement(renders[0], renders[1], refs[0], refs[1], inside)
    signal = float(refs[0][inside].mean())  # the reflection, about 0.03
    assert abs(diff) < 4 * se and 4 * se < 0.05 * signal, (diff, se, signal)
    # the light below the surface is far above that noise: a render that left out f_r, or a reference that kept
    # the interior, would fail
    subsurface = render_translucent_reference(obj, env, camera, 16, spp=16, appearance="subsurface")
    assert float(subsurface[inside].mean()) > 100 * se


@pytest.mark.parametrize("strategy", ["light", "model", "mis"])
def test_strategies_are_unbiased(strategy):
    """light, model and mis (full appearance) agree with a brute-force estimate (uniform sphere sampling at 8x
    the samples) within their noise; mis is the default for a model with a sampler and its pdf."""
    from neumat.render.translucent import default_strategy, render_translucent
    obj, camera = _setup(16)
    env = _smooth_environment()
    brute = [render_translucent(_Uniform(), obj, env, camera, 16, spp=1024, strategy="model", seed=s,
                                appearance="full") for s in (10, 11)]
    got = [render_translucent(_Lobe(), obj, env, camera, 16, spp=256, strategy=strategy, seed=s, appearance="full")
           for s in (12, 13)]
    ratio, diff, se = _agreement(got[0], got[1], brute[0], brute[1])
    subsurface = float(render_translucent(_Lobe(), obj, env, camera, 16, spp=64, strategy=strategy).mean())
    assert ratio < 2 and abs(diff) < 4 * se and 4 * se < 0.05 * subsurface, (ratio, diff, se, subsurface)
    assert default_strategy(_Lobe()) == "mis" and default_strategy(_Constant((1, 1, 1))) == "light"


def test_mis_through_one_lobe_per_batch_equals_mis_through_sample_and_pdf():
    """A model with incident_lobe is sampled and its densities taken from one lobe per batch (its sampler network
    runs once): the image equals that of the same lobe through sample_incident and incident_pdf."""
    from neumat.render.translucent import _pixel_rays, render_translucent
    obj, camera = _setup(8)
    env = _smooth_environment()
    once = _LobeOnce()
    hits = int(obj.first_hits(*_pixel_rays(camera, 8, 16, torch.Generator().manual_seed(3)))[0].sum())
    got = render_translucent(once, obj, env, camera, 8, spp=16, strategy="mis", seed=3, batch=256)
    want = render_translucent(_Lobe(), obj, env, camera, 8, spp=16, strategy="mis", seed=3, batch=256)
    torch.testing.assert_close(got, want, rtol=1e-6, atol=1e-9)
    assert hits > 256 and once.lobes == -(-hits // 256)  # one lobe per batch


def test_background_pixels_are_the_environment():
    from neumat.render.translucent import _pixel_rays, render_translucent
    obj, camera = _setup(16)
    env = _smooth_environment()
    img = render_translucent(_Zero(), obj, env, camera, 16, spp=4, seed=5, appearance="full")
    o, d = _pixel_rays(camera, 16, 4, torch.Generator().manual_seed(5))
    miss = ~obj.first_hits(o, d)[0].reshape(16, 16, 4).any(-1)
    background = env.eval(d.float()).reshape(16, 16, 4, 3).mean(2)
    assert int(miss.sum()) > 50 and torch.equal(img[miss], background[miss])
    assert torch.equal(render_translucent(_Zero(), obj, env, camera, 16, spp=4, seed=5)[miss],
                       torch.zeros(int(miss.sum()), 3))  # the subsurface appearance keeps a black background


def test_bad_appearance_and_missing_pdf():
    from neumat.render.translucent import render_translucent, render_translucent_reference
    obj, camera = _setup()
    env = EnvironmentMap(torch.ones(4, 8, 3))
    with pytest.raises(InputError, match="appearance"):
        render_translucent(_Zero(), obj, env, camera, 8, appearance="surface")
    with pytest.raises(InputError, match="incident_pdf"):
        render_translucent(_Constant((1, 1, 1)), obj, env, camera, 8, strategy="mis")
    with pytest.raises(InputError, match="appearance"):
        render_translucent_reference(obj, env, camera, 8, appearance="surface")
