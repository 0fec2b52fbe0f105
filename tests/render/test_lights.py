"""Lights: environment-map importance sampling (chi-square on the solid-angle pdf), the equirectangular
mapping, delta lights, the procedural sky, and spec / file errors."""
import math

import numpy as np
import pytest
import torch

from neumat import DataFormatError, InputError, UnknownNameError
from neumat.render.envmaps import dir_to_equirect, downsample_envmap, equirect_to_dir, sky_envmap
from neumat.render.lights import (ConstantEnvironment, DirectionalLight, EnvironmentMap, PointLight,
                                  make_light)
from neumat.testing.chi2 import chi2_directions


def _blobby_map(h=16, w=32, seed=0):
    """A random map with dark texels, an empty row and a bright texel at the zenith row."""
    g = np.random.default_rng(seed)
    img = (g.random((h, w, 3)) ** 4).astype(np.float32)
    img[5] = 0
    img[0, 3] = 50.0
    return img


def _smooth_map(h=128, w=256):
    """Broad lobes, a bright zenith and a dim floor: smooth at the scale of the chi-square cells, so the
    test's quadrature of the piecewise-constant pdf is accurate."""
    v, u = (np.arange(h) + 0.5) / h, (np.arange(w) + 0.5) / w
    uu, vv = np.meshgrid(u, v)
    d = equirect_to_dir(torch.from_numpy(np.stack([uu.ravel(), vv.ravel()], -1))).numpy()
    a, b = np.array([0.6, 0.64, 0.48]), np.array([0.0, -0.6, -0.8])
    lum = (0.05 + 8 * np.exp(6 * (d @ a - 1)) + 2 * np.exp(4 * (d @ b - 1)) + 0.5 * np.clip(d[:, 1], 0, None)
           + 3 * np.exp(8 * (d[:, 1] - 1)))
    return np.stack([lum, 0.8 * lum, 0.6 * lum], -1).reshape(h, w, 3).astype(np.float32)


@pytest.mark.parametrize("rotation", [0.0, 70.0])
def test_environment_sampling_matches_its_solid_angle_pdf(rotation):
    env = EnvironmentMap(_smooth_map(), rotation=rotation)

    def sample(u):
        s = env.sample(torch.zeros(len(u), 3), u)
        return s.wi, s.pdf > 0

    r = chi2_directions(sample, env.pdf, n_samples=300_000, res=(24, 48), sphere=True, n_tests=2)
    assert r, r.message
    assert r.pdf_integral == pytest.approx(1.0, abs=2e-3)


@pytest.mark.parametrize("spec", ["blobby", "env:sky,width=128,rotation=20"])
def test_environment_sample_agrees_with_eval_and_pdf(spec):
    """Also for maps with black texels and a sharp sun, where the chi-square quadrature is unreliable."""
    env = EnvironmentMap(_blobby_map(), rotation=30.0, scale=2.0) if spec == "blobby" else make_light(spec)
    u = torch.rand(4096, 2, generator=torch.Generator().manual_seed(1))
    s = env.sample(torch.zeros(4096, 3), u)
    torch.testing.assert_close(s.wi.norm(dim=-1), torch.ones(4096))
    torch.testing.assert_close(s.radiance, env.eval(s.wi))
    torch.testing.assert_close(s.pdf, env.pdf(s.wi), rtol=2e-3, atol=0)
    assert (s.radiance.sum(-1) > 0).all()  # never samples black texels
    # the estimator L / pdf integrates the map: mean over samples ~ integral of L over the sphere
    h, w = env.image.shape[:2]
    theta = (torch.arange(h) + 0.5) * math.pi / h
    d_omega = 2 * math.pi ** 2 * torch.sin(theta) / (h * w)
    exact = (env.image * d_omega[:, None, None]).sum((0, 1))
    est = (s.radiance / s.pdf[:, None]).mean(0)
    torch.testing.assert_close(est, exact, rtol=0.05, atol=0)


def test_equirect_mapping_follows_mitsuba():
    uv = torch.tensor([[0.0, 0.5], [0.25, 0.5], [0.5, 0.5], [0.3, 0.0], [0.7, 1.0]], dtype=torch.float64)
    d = equirect_to_dir(uv)
    expect = torch.tensor([[0, 0, -1], [1, 0, 0], [0, 0, 1], [0, 1, 0], [0, -1, 0]], dtype=torch.float64)
    torch.testing.assert_close(d, expect, atol=1e-12, rtol=0)
    g = torch.Generator().manual_seed(0)
    uv = torch.rand(1000, 2, generator=g, dtype=torch.float64) * 0.98 + 0.01
    torch.testing.assert_close(dir_to_equirect(equirect_to_dir(uv)), uv)


def test_environment_lookup_is_per_texel_and_rotation_turns_about_y():
    img = np.zeros((4, 8, 3), np.float32)
    img[1, 2] = (1.0, 2.0, 3.0)  # theta in [45, 90] deg, phi in [90, 135] deg
    env = EnvironmentMap(img, rotation=90.0)
    local = equirect_to_dir(torch.tensor([[2.5 / 8, 1.5 / 4]]))
    c, s = 0.0, 1.0  # +90 deg about y: (x, y, z) -> (z, y, -x)
    world = torch.stack([local[:, 2] * s + local[:, 0] * c, local[:, 1], -local[:, 0] * s + local[:, 2] * c], -1)
    torch.testing.assert_close(env.eval(world), torch.tensor([[1.0, 2.0, 3.0]]))
    assert env.eval(local).abs().sum() == 0


def test_delta_lights_and_constant_environment():
    p = torch.tensor([[0.0, 0.0, 0.0], [1.0, 2.0, 2.0]])
    pl = make_light("point:1/2/4,intensity=8")
    s = pl.sample(p, torch.zeros(2, 2))
    torch.testing.assert_close(s.radiance[:, 0], torch.tensor([8 / 21, 8 / 4]))
    torch.testing.assert_close(s.wi[1], torch.tensor([0.0, 0.0, 1.0]))
    torch.testing.assert_close(s.distance, torch.tensor([math.sqrt(21), 2.0]))
    assert pl.is_delta and pl.pdf(s.wi).abs().sum() == 0 and pl.background(s.wi).abs().sum() == 0
    default = make_light("point")  # irradiance pi at the origin
    assert default.sample(torch.zeros(1, 3), torch.zeros(1, 2)).radiance[0, 0].item() == pytest.approx(math.pi)
    dl = make_light("dir:0/3/4,irradiance=1/2/3")
    s = dl.sample(p, torch.zeros(2, 2))
    torch.testing.assert_close(s.wi, torch.tensor([[0.0, 0.6, 0.8]] * 2))
    torch.testing.assert_close(s.radiance, torch.tensor([[1.0, 2.0, 3.0]] * 2))
    assert isinstance(make_light("dir"), DirectionalLight) and isinstance(default, PointLight)
    c = make_light("const:0.2/0.3/0.4")
    assert isinstance(c, ConstantEnvironment)
    s = c.sample(p, torch.rand(2, 2))
    torch.testing.assert_close(s.pdf, torch.full((2,), 1 / (4 * math.pi)))
    torch.testing.assert_close(c.background(s.wi), torch.tensor([[0.2, 0.3, 0.4]] * 2))


def test_sky_irradiance_matches_its_parameters():
    img = torch.from_numpy(sky_envmap(width=512, sun_elevation=30.0, sun_irradiance=3.0, sky_irradiance=1.0))
    h, w = img.shape[:2]
    v = (torch.arange(h) + 0.5) / h
    u = (torch.arange(w) + 0.5) / w
    vv, uu = torch.meshgrid(v, u, indexing="ij")
    d = equirect_to_dir(torch.stack([uu.reshape(-1), vv.reshape(-1)], -1).double()).float()
    d_omega = (2 * math.pi ** 2 * torch.sin(vv * math.pi) / (h * w)).reshape(-1)
    up = (img.reshape(-1, 3).mean(-1) * d[:, 1].clamp(min=0) * d_omega).sum()
    assert up.item() == pytest.approx(1.0 + 3.0 * math.sin(math.radians(30)), rel=0.03)
    assert (img >= 0).all() and img[h // 2 + 2:].max() < img[: h // 2].max() / 100  # ground is dim


def test_light_spec_errors(tmp_path):
    with pytest.raises(UnknownNameError, match="point.*dir.*const:VALUE.*env:PATH.*env:sky"):
        make_light("spot")
    with pytest.raises(UnknownNameError, match="did you mean point"):
        make_light("pont")
    with pytest.raises(InputError, match="env:PATH"):
        make_light("env")
    with pytest.raises(InputError, match="does not exist"):
        make_light(f"env:{tmp_path / 'missing.hdr'}")
    with pytest.raises(InputError, match=".hdr or .exr"):
        make_light(f"env:{tmp_path / 'map.png'}")
    corrupt = tmp_path / "corrupt.hdr"
    corrupt.write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 64 +X 128\n" + b"\x02\x02" * 10)
    with pytest.raises(DataFormatError, match="corrupt.hdr"):
        make_light(f"env:{corrupt}")
    with pytest.raises(InputError, match="unknown option.*bogus.*intensity"):
        make_light("point,bogus=1")
    with pytest.raises(InputError, match="a/b/c"):
        make_light("dir:1/2")
    with pytest.raises(InputError, match="black"):
        EnvironmentMap(np.zeros((4, 8, 3), np.float32))
    with pytest.raises(InputError, match="NaN"):
        EnvironmentMap(np.full((4, 8, 3), np.nan, np.float32))


def test_real_environment_maps_load_and_sample(shared_data):
    for path in sorted((shared_data / "envmap").glob("*")):
        env = make_light(f"env:{path}")
        s = env.sample(torch.zeros(2048, 3), torch.rand(2048, 2, generator=torch.Generator().manual_seed(0)))
        assert torch.isfinite(s.radiance).all() and (s.pdf > 0).all(), path.name
        torch.testing.assert_close(s.pdf, env.pdf(s.wi), rtol=2e-3, atol=0)


def test_downsample_envmap_keeps_the_mean_of_each_block():
    rng = np.random.default_rng(0)
    img = rng.random((37, 70, 3)).astype(np.float32)  # 37 x 70 -> 4 x 8: blocks of 9 x 8, the rest dropped
    small = downsample_envmap(img, 8)
    assert small.shape == (4, 8, 3) and small.dtype == np.float32
    assert np.allclose(small[2, 5], img[18:27, 40:48].mean((0, 1)), atol=1e-6)
    assert np.allclose(downsample_envmap(img[:36, :64], 64 // 8).mean(), img[:36, :64].mean(), atol=1e-6)
    with pytest.raises(InputError, match="even integer"):
        downsample_envmap(img, 7)
    with pytest.raises(InputError, match="at least"):
        downsample_envmap(img, 128)


@pytest.mark.parametrize("width", [16, 512])
def test_sky_sun_gives_its_irradiance_at_any_width(width):
    """At 16 texels across no texel centre lies on the 2-degree disc: the sun goes to the nearest texel (it
    used to divide by zero and fill the map with NaN)."""
    sun = torch.tensor([math.cos(math.radians(35)) * math.sin(math.radians(40)), math.sin(math.radians(35)),
                        math.cos(math.radians(35)) * math.cos(math.radians(40))], dtype=torch.float64)
    with_sun, without = sky_envmap(width=width), sky_envmap(width=width, sun_irradiance=0.0)
    assert np.isfinite(with_sun).all()
    h, w = with_sun.shape[:2]
    v, u = (torch.arange(h) + 0.5) / h, (torch.arange(w) + 0.5) / w
    vv, uu = torch.meshgrid(v, u, indexing="ij")
    d = equirect_to_dir(torch.stack([uu.reshape(-1), vv.reshape(-1)], -1).double())
    d_omega = (2 * math.pi ** 2 * torch.sin(vv * math.pi) / (h * w)).reshape(-1).double()
    disc = torch.from_numpy(with_sun - without).reshape(-1, 3).double().mean(-1)
    assert float((disc * (d @ sun).clamp(min=0) * d_omega).sum()) == pytest.approx(3.0, rel=1e-4)
