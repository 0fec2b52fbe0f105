"""BTF generator: ray-marched height field with cast shadows, masking and parallax."""
from __future__ import annotations

import math

import pytest
import torch

from neumat import InputError
from neumat.io.texture_set import TextureSet
from neumat.reflectance.btf_generate import (
    elevation_groups,
    generate_btf,
    lambert_shader,
    sensor_noise,
)
from neumat.reflectance.procedural_texture import procedural_texture_set
from neumat.reflectance.heightfield import HeightField

SIZE = 24
RELIEF = 3.0


def ridge_set() -> TextureSet:
    """A ridge of height 1 along v over columns 8..15, white, with a red stripe on its top (columns 11, 12)."""
    height = torch.zeros(SIZE, SIZE)
    height[:, 8:16] = 1
    color = torch.ones(SIZE, SIZE, 3) * 0.8
    color[:, 11:13] = torch.tensor([0.8, 0.0, 0.0])
    n = torch.zeros(SIZE, SIZE, 3)
    n[..., 2] = 1
    return TextureSet(color=color, normal=n, roughness=torch.full((SIZE, SIZE), 0.5),
                      metalness=torch.zeros(SIZE, SIZE), height=height, name="ridge")


def _dir(theta_deg: float) -> torch.Tensor:
    t = math.radians(theta_deg)
    return torch.tensor([[math.sin(t), 0.0, math.cos(t)]])


def test_grazing_light_casts_shadows_only_where_expected():
    light = _dir(75.0)                       # light from +x: shadows fall on the -x side of the ridge
    view = _dir(0.0)
    on = generate_btf(ridge_set(), light, view, relief=RELIEF, spp=1, shader=lambert_shader).data[0, 0]
    off = generate_btf(ridge_set(), light, view, relief=RELIEF, spp=1, shader=lambert_shader,
                       shadows=False).data[0, 0]
    lit = 0.8 / math.pi
    # shadow length RELIEF * tan(75 deg) = 11.2 texels to the left of column 8
    assert torch.allclose(off[:, 1:7], torch.full_like(off[:, 1:7], lit), atol=1e-4)
    assert float(on[:, 1:7].abs().max()) == 0.0
    # the lit flat side and the ridge top are identical with and without occlusion
    assert torch.allclose(on[:, 17:21], off[:, 17:21]) and torch.allclose(on[:, 9:15], off[:, 9:15])
    assert torch.allclose(on[:, 17:21], torch.full_like(on[:, 17:21], lit), atol=1e-4)


def test_oblique_view_shows_parallax_and_masking():
    ts = ridge_set()
    light = _dir(0.0)
    views = torch.cat([_dir(0.0), _dir(60.0)])
    img = generate_btf(ts, light, views, relief=RELIEF, spp=4, shader=lambert_shader).data[0]
    z_ref = float((ts.height * RELIEF).mean())

    def red_centre(im):
        redness = (im[..., 0] - im[..., 1]).mean(0)          # per column
        cols = torch.arange(SIZE, dtype=torch.float32) + 0.5
        return float((redness * cols).sum() / redness.sum())

    shift = red_centre(img[0]) - red_centre(img[1])
    assert shift == pytest.approx((RELIEF - z_ref) * math.tan(math.radians(60)), abs=0.3)
    # masking: seen from +x at 60 deg, the floor left of the ridge (s = 4 .. 7.5) is hidden behind it
    hf = HeightField(ts.height * RELIEF)
    s0 = torch.full((1,), 6.0)  # the ray through the plane at s = 6 meets the ridge top at s = 9.5
    hit = hf.intersect_view(s0, torch.full((1,), 5.0), _dir(60.0))
    assert float(hit[0, 2]) == pytest.approx(RELIEF, abs=1e-3)


def test_generated_btf_of_a_procedural_set_is_finite_and_positive():
    from neumat.reflectance.btf import direction_set
    d = direction_set(7)
    btf = generate_btf(procedural_texture_set("bumps", 8), d, d, relief=2.0, spp=1)
    assert btf.data.shape == (7, 7, 8, 8, 3)
    assert bool(torch.isfinite(btf.data).all()) and float(btf.data.min()) >= 0 and float(btf.data.max()) > 0


def test_lights_generated_together_equal_each_light_alone():
    """The generator shades and shadow-marches all lights of one elevation at once; every light must give
    what it gives alone (same march steps), with cast shadows and a metal BRDF."""
    from neumat.reflectance.btf import direction_set
    d = direction_set("rings:3x30")
    ts = procedural_texture_set("dents", 10, seed=1)
    together = generate_btf(ts, d, d[:3], relief=4.0, spp=4).data
    for l in (0, 5, 16):
        alone = generate_btf(ts, d[l:l + 1], d[:3], relief=4.0, spp=4).data
        torch.testing.assert_close(together[l:l + 1], alone, rtol=1e-6, atol=1e-7)


def test_elevation_groups_cover_every_direction_once_by_ring():
    from neumat.reflectance.btf import direction_set
    d = direction_set("hemi151")
    groups = elevation_groups(d, per_direction=100, max_points=2000)       # at most 20 directions per group
    flat = torch.cat(groups)
    assert sorted(flat.tolist()) == list(range(151))
    assert all(len(g) <= 20 and float(d[g, 2].max() - d[g, 2].min()) < 1e-6 for g in groups)
    assert len(elevation_groups(d, per_direction=100)) == 6                 # one group per ring


def test_sensor_noise_is_relative_seeded_and_off_by_default():
    from neumat.reflectance.btf import direction_set
    d = direction_set(5)
    clean = generate_btf(procedural_texture_set("bumps", 8), d, d, relief=2.0, spp=1)
    noisy = generate_btf(procedural_texture_set("bumps", 8), d, d, relief=2.0, spp=1, noise=0.05, noise_seed=3)
    lit = clean.data > 1e-3
    rel = (noisy.data[lit] / clean.data[lit] - 1)
    assert abs(float(rel.std()) - 0.05) < 0.005 and abs(float(rel.mean())) < 0.005
    again = sensor_noise(clean.data, 0.05, seed=3)
    assert torch.equal(again, noisy.data) and not torch.equal(sensor_noise(clean.data, 0.05, seed=4), again)
    assert float(sensor_noise(torch.full((1000,), 0.01), 2.0).min()) == 0          # clamped, never negative


def test_bad_generator_input():
    d = _dir(0.0)
    with pytest.raises(InputError, match="noise"):
        generate_btf(ridge_set(), d, d, noise=-0.1)
    with pytest.raises(InputError, match="square"):
        generate_btf(ridge_set(), d, d, spp=3)
    with pytest.raises(InputError, match="upper-hemisphere"):
        generate_btf(ridge_set(), -d, d)
