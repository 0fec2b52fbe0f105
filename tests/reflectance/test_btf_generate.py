"""BTF generator: ray-marched height field with cast shadows, masking and parallax."""
from __future__ import annotations

import math

import pytest
import torch

from neumat import InputError
from neumat.io.texture_set import TextureSet
from neumat.reflectance.btf_generate import (
    elevation_groups,
    fibre_shader,
    generate_btf,
    lambert_shader,
    principled_shader,
    sensor_noise,
)
from neumat.reflectance.fibre_field import fibre_field
from neumat.reflectance.microfacet import principled_eval
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
    with pytest.raises(InputError, match="interreflection"):
        generate_btf(ridge_set(), d, d, interreflection=5)
    with pytest.raises(InputError, match="fibres"):
        generate_btf(ridge_set(), d, d, fibres=1.5)
    with pytest.raises(InputError, match="principled"):
        generate_btf(ridge_set(), d, d, fibres=0.5, shader=lambert_shader)
    with pytest.raises(InputError, match="weave"):
        generate_btf(ridge_set(), d, d, fibres=0.5, fibre_direction="weave:0")
    with pytest.raises(InputError, match="noise"):
        generate_btf(ridge_set(), d, d, noise=-0.1)
    with pytest.raises(InputError, match="square"):
        generate_btf(ridge_set(), d, d, spp=3)
    with pytest.raises(InputError, match="upper-hemisphere"):
        generate_btf(ridge_set(), -d, d)


# --- one bounce of inter-reflection ---------------------------------------------------------------------------

GROOVE_W, GROOVE_H, GROOVE_RHO = 32, 16, 0.8


def groove_set() -> TextureSet:
    """A periodic V-groove along t, 45-degree faces: z = |s - 16.5| over s in [0.5, 32.5] (peak at column 0,
    valley at column 16, texel centres on the kinks, so the bilinear surface is exactly the V)."""
    z = (torch.arange(GROOVE_W, dtype=torch.float32) - GROOVE_W / 2).abs().expand(GROOVE_H, GROOVE_W).clone()
    n = torch.zeros(GROOVE_H, GROOVE_W, 3)
    n[..., 2] = 1
    return TextureSet(color=torch.full((GROOVE_H, GROOVE_W, 3), GROOVE_RHO), normal=n,
                      roughness=torch.full((GROOVE_H, GROOVE_W), 0.5), metalness=torch.zeros(GROOVE_H, GROOVE_W),
                      height=z, name="groove")


def groove_one_bounce(col: int, theta_deg: float) -> float:
    """Independent one-bounce reference for the texel column `col` of `groove_set`, seen from above, light at
    theta_deg from the zenith towards +s: the 2D form factor of an infinite groove, rho int L0(y) cos_x cos_y /
    (2 r) dy over the opposite face (the only one visible), L0 = rho / pi x the light's cosine on the
    generator's shading normals (bilinear between texel centres) x the analytic cast shadow (the ray towards
    the light must clear the peak at s = 32.5), divided by cos(theta) like the stored value."""
    w, rho = GROOVE_W, GROOVE_RHO
    light = torch.tensor([math.sin(math.radians(theta_deg)), math.cos(math.radians(theta_deg))], dtype=torch.float64)
    left = col < w // 2
    x = torch.tensor([col + 0.5, abs(col - w / 2)], dtype=torch.float64)
    nx = torch.tensor([1.0 if left else -1.0, 1.0], dtype=torch.float64) / math.sqrt(2)
    s = (torch.linspace(w / 2 + 0.5, w + 0.5, 200001, dtype=torch.float64) if left
         else torch.linspace(0.5, w / 2 + 0.5, 200001, dtype=torch.float64))[1:-1]
    y = torch.stack([s, (s - w / 2 - 0.5).abs()], -1)
    ny = torch.tensor([-1.0 if left else 1.0, 1.0], dtype=torch.float64) / math.sqrt(2)
    r = y - x
    dist = r.norm(dim=-1)
    rh = r / dist[:, None]
    cos_x, cos_y = (rh @ nx).clamp(min=0), (-rh @ ny).clamp(min=0)
    nmap = HeightField(groove_set().height).normals()[0].double()[:, [0, 2]]        # (W, 2), same along t
    u = s - 0.5
    j0 = torch.floor(u).long()
    f = (u - j0)[:, None]
    n = (1 - f) * nmap[j0 % w] + f * nmap[(j0 + 1) % w]
    n = n / n.norm(dim=-1, keepdim=True)
    clears_peak = y[:, 1] + (w + 0.5 - y[:, 0]) * light[1] / light[0] >= w / 2 if light[0] > 0 else True
    l0 = rho / math.pi * (n @ light).clamp(min=0) * ((-rh * n).sum(-1) > 0) * clears_peak
    return float(rho * (l0 * cos_x * cos_y / (2 * dist)).sum() * (s[1] - s[0]) * math.sqrt(2) / light[1])


@pytest.mark.parametrize("theta, cols", [(0.0, (2, 6, 10, 14)), (60.0, (18, 22, 26, 30))])
def test_one_bounce_in_a_v_groove_matches_the_form_factor_quadrature(theta, cols):
    """Overhead light: both faces lit, the left face's texels receive the right face's light. Light at 60 deg
    from +s: the right face is unlit and receives the left face's light, part of which the peak shadows."""
    ts, light, view = groove_set(), _dir(theta), _dir(0.0)
    direct = generate_btf(ts, light, view, relief=1.0, spp=1, shader=lambert_shader).data[0, 0, ..., 0]
    both = generate_btf(ts, light, view, relief=1.0, spp=1, shader=lambert_shader, interreflection=256,
                        interreflection_seed=5).data[0, 0, ..., 0]
    bounce = (both - direct).mean(0)                                     # mean over the 16 rows (jitter)
    for col in cols:
        ref = groove_one_bounce(col, theta)
        assert ref > 0.05 * float(direct.max())                        # a real effect
        assert float(bounce[col]) == pytest.approx(ref, rel=0.06), col     # Monte Carlo: about 1.5 % std


def test_interreflection_adds_exactly_nothing_on_a_flat_surface():
    """Every bounce ray of a flat surface escapes: the BTF is the direct one, bit for bit (principled BRDF)."""
    from neumat.reflectance.btf import direction_set
    ts = procedural_texture_set("bumps", 8, seed=2)
    d = direction_set(7)
    direct = generate_btf(ts, d, d, relief=0.0, spp=1).data
    assert torch.equal(generate_btf(ts, d, d, relief=0.0, spp=1, interreflection=16).data, direct)


def test_interreflection_raises_a_white_lambert_albedo_but_not_above_one():
    """White Lambert egg-crate: the apparent albedo (pi x the mean over cosine-distributed views) loses light
    to the bumps without interreflection; one bounce gives part of it back, never more than all."""
    from neumat.warp.hemisphere import sample_cosine_hemisphere
    n = 12
    a = (torch.arange(n) + 0.5) / n * 2 * math.pi
    flat = torch.zeros(n, n, 3)
    flat[..., 2] = 1
    ts = TextureSet(color=torch.ones(n, n, 3), normal=flat, roughness=torch.full((n, n), 0.5),
                    metalness=torch.zeros(n, n), height=torch.sin(a)[None, :] * torch.cos(a)[:, None], name="egg")
    j, i = torch.meshgrid(torch.arange(5), torch.arange(5), indexing="ij")
    views = sample_cosine_hemisphere((torch.stack([i.reshape(-1), j.reshape(-1)], -1) + 0.5) / 5)
    light = _dir(30.0)
    direct = math.pi * float(generate_btf(ts, light, views, relief=2.0, spp=1, shader=lambert_shader).data.mean())
    both = math.pi * float(generate_btf(ts, light, views, relief=2.0, spp=1, shader=lambert_shader,
                                        interreflection=16).data.mean())
    assert direct < 0.95 and direct + 0.5 * (1 - direct) < both <= 1.0


# --- anisotropic fibres ----------------------------------------------------------------------------------------

def flat_set(n: int = 6) -> TextureSet:
    g = torch.Generator().manual_seed(0)
    normal = torch.zeros(n, n, 3)
    normal[..., 2] = 1
    return TextureSet(color=torch.rand(n, n, 3, generator=g), normal=normal,
                      roughness=0.2 + 0.3 * torch.rand(n, n, generator=g),
                      metalness=(torch.rand(n, n, generator=g) > 0.5).float(), height=torch.zeros(n, n), name="flat")


def test_fibres_on_a_flat_surface_are_the_anisotropic_principled_brdf_in_the_rotated_frame():
    from neumat.reflectance.btf import direction_set
    ts, d = flat_set(), direction_set(7)
    btf = generate_btf(ts, d, d, spp=1, fibres=0.8, fibre_direction="angle:30").data          # (L, V, H, W, 3)
    c, s = math.cos(math.radians(30)), math.sin(math.radians(30))
    rot = torch.tensor([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])                       # world -> fibre frame
    li, vi = torch.meshgrid(torch.arange(7), torch.arange(7), indexing="ij")
    wi, wo = d[li.reshape(-1)] @ rot.T, d[vi.reshape(-1)] @ rot.T
    for r, col in ((0, 0), (2, 5), (4, 3)):
        ref = principled_eval(wi, wo, ts.color[r, col], float(ts.metalness[r, col]), float(ts.roughness[r, col]), 0.8)
        torch.testing.assert_close(btf[:, :, r, col].reshape(-1, 3), ref, rtol=1e-4, atol=1e-6)
    iso = generate_btf(ts, d, d, spp=1).data
    assert float(((btf - iso).abs() > 0.1 * iso).float().mean()) > 0.2                  # anisotropy shows


def test_fibre_btf_is_reciprocal_on_a_flat_weave():
    from neumat.reflectance.btf import direction_set
    d = direction_set(9)
    btf = generate_btf(flat_set(), d, d, spp=1, fibres=0.9, fibre_direction="weave:2").data
    torch.testing.assert_close(btf, btf.transpose(0, 1), rtol=1e-3, atol=1e-5)      # float32 GGX at grazing angles


def test_fibre_frame_leaves_an_isotropic_lobe_unchanged_on_a_relief():
    """Anisotropy -> 0 with grain directions on a bumpy relief gives the isotropic BTF: the fibre frames only
    rotate the tangent about the shading normal."""
    from neumat.reflectance.btf import direction_set
    ts, d = procedural_texture_set("weave", 10, seed=1), direction_set(7)
    iso = generate_btf(ts, d, d, relief=3.0, spp=1).data
    fib = generate_btf(ts, d, d, relief=3.0, spp=1, fibres=1e-6, fibre_direction="grain").data
    torch.testing.assert_close(fib, iso, rtol=1e-4, atol=1e-5)
    assert fibre_shader(0.0)(d, d.flip(0), torch.ones(7, 3), torch.zeros(7), torch.full((7,), 0.4)).equal(
        principled_shader(d, d.flip(0), torch.ones(7, 3), torch.zeros(7), torch.full((7,), 0.4)))


def test_grain_follows_ridges_and_weave_alternates():
    s = torch.arange(16, dtype=torch.float32)
    along_t = torch.sin(2 * math.pi * s / 8)[None, :].expand(16, 16)        # ridges along t (varies with s)
    along_s = along_t.T.flip(0)                                              # ridges along s
    diagonal = torch.sin(2 * math.pi * (s[None, :] + s.flip(0)[:, None]) / 8)   # varies along s + t
    for height, angle in ((along_t, 90.0), (along_s, 0.0), (diagonal, 135.0)):
        doubled = fibre_field(height, "grain")
        a = math.radians(2 * angle)
        torch.testing.assert_close(doubled, torch.tensor([math.cos(a), math.sin(a)]).expand(16, 16, 2),
                                   atol=1e-4, rtol=0)
    weave = fibre_field(torch.zeros(4, 4), "weave:2")
    assert weave[0, 0].tolist() == [1.0, 0.0] and weave[0, 2].tolist() == [-1.0, 0.0]
    assert weave[2, 2].tolist() == [1.0, 0.0]


def test_bounce_drawn_from_the_brdf_agrees_with_cosine_sampling_and_is_less_noisy():
    """Glossy bumps: the principled shader's bounce directions come from its BRDF; the same BRDF behind another
    callable is sampled cosine-weighted. Both estimate the same bounce (means over 10 800 entries agree); the
    BRDF-sampled one varies less between two seeds."""
    from dataclasses import replace

    from neumat.reflectance.btf import direction_set
    ts = procedural_texture_set("bumps", 12, seed=1)
    ts = replace(ts, roughness=torch.full_like(ts.roughness, 0.25))
    d = direction_set(5)
    plain = generate_btf(ts, d, d, relief=4.0, spp=1).data
    bounces = {name: [generate_btf(ts, d, d, relief=4.0, spp=1, shader=shader, interreflection=16,
                                   interreflection_seed=seed).data - plain for seed in (0, 1)]
               for name, shader in (("brdf", principled_shader), ("cosine", lambda *a: principled_shader(*a)))}
    mean = {k: float((a + b).mean()) / 2 for k, (a, b) in bounces.items()}
    spread = {k: float((a - b).pow(2).mean().sqrt()) for k, (a, b) in bounces.items()}
    assert mean["brdf"] > 0.05 * float(plain.mean())                         # a real effect
    assert mean["brdf"] == pytest.approx(mean["cosine"], rel=0.1)
    assert spread["brdf"] < 0.9 * spread["cosine"]
