"""Procedural detail texture sets (`neumat.reflectance.detail_texture`), writing a texture set as a folder
(`neumat.io.texture_set.write_texture_set`), and the regime statistics (`neumat.reflectance.texture_statistics`):
tilts from a known height field, the noise-corrected rank on matrices of known rank, a uniform set's rank 0."""
from __future__ import annotations

import math

import pytest
import torch

from neumat.core.errors import InputError
from neumat.io.texture_set import TextureSet, load_texture_set, normals_from_height, write_texture_set
from neumat.reflectance.detail_texture import DETAIL_KINDS, POLISHED_KINDS, detail_texture_set
from neumat.reflectance.texture_statistics import noise_corrected_rank, separability_rank, texture_statistics


@pytest.mark.parametrize("kind", DETAIL_KINDS)
def test_detail_sets_have_strong_normal_and_roughness_detail_and_follow_their_seed(kind):
    ts = detail_texture_set(kind, 32, seed=1)
    assert ts.size == (32, 32) and ts.name == f"detail_{kind}_1"
    torch.testing.assert_close(ts.normal.norm(dim=-1), torch.ones(32, 32))
    assert float(ts.height.min()) == 0 and float(ts.height.max()) == 1
    tilt = torch.rad2deg(torch.acos(ts.normal[..., 2])).mean()
    assert tilt > 3 and ts.roughness.std() > 0.03, (kind, float(tilt), float(ts.roughness.std()))
    # normals are the height field's at the set's own scale
    torch.testing.assert_close(ts.normal, normals_from_height(ts.height, ts.height_scale))
    again, other = detail_texture_set(kind, 32, seed=1), detail_texture_set(kind, 32, seed=2)
    assert torch.equal(again.height, ts.height) and not torch.equal(other.height, ts.height)


def test_the_polished_set_is_a_near_mirror_metal_with_gentle_relief():
    """Issue 55's regime: alpha = roughness^2 <= 0.01 everywhere, metal, tilts of about a degree, seeded."""
    assert "polished" in POLISHED_KINDS and "polished" not in DETAIL_KINDS
    ts = detail_texture_set("polished", 64, seed=1)
    assert ts.name == "detail_polished_1" and float(ts.metalness.min()) == 1
    assert float(ts.roughness.max() ** 2) <= 0.01 and float(ts.roughness.std()) < 1e-6
    tilt = torch.rad2deg(torch.acos(ts.normal[..., 2].clamp(max=1)))
    assert 0.3 < float(tilt.mean()) < 3 and float(tilt.max()) < 6, (float(tilt.mean()), float(tilt.max()))
    torch.testing.assert_close(ts.normal, normals_from_height(ts.height, ts.height_scale))
    assert not torch.equal(detail_texture_set("polished", 64, seed=2).height, ts.height)


@pytest.mark.parametrize("args, match", [(("wood", 32), "unknown kind 'wood'"), (("foil", 8), "size"),
                                         (("foil", 32, -1), "seed")])
def test_detail_sets_refuse_bad_arguments(args, match):
    with pytest.raises(InputError, match=match):
        detail_texture_set(*args)


def test_a_written_texture_set_reads_back(tmp_path):
    ts = detail_texture_set("chainmail", 32)
    back = load_texture_set(write_texture_set(ts, tmp_path / "set"))
    assert back.size == ts.size and back.name == "set"
    assert (back.color - ts.color).abs().max() < 0.01            # 8-bit sRGB
    assert (back.normal - ts.normal).abs().max() < 0.01          # 8-bit normal map
    for name in ("roughness", "metalness", "height"):            # 16-bit
        assert (getattr(back, name) - getattr(ts, name)).abs().max() < 2e-5, name
    (tmp_path / "file").write_text("x")
    with pytest.raises(InputError, match="is a file"):
        write_texture_set(ts, tmp_path / "file")


def test_tilt_statistics_of_a_known_slope():
    """A sine along u with slopes up to tan(20 deg): the mean tilt is that of its central differences (slope
    2 pi A cos(2 pi u) times sin(2 pi / n) / (2 pi / n)), computed here in closed form."""
    n = 64
    u = (torch.arange(n) + 0.5) / n
    amplitude = math.tan(math.radians(20)) / (2 * math.pi)     # z = A sin(2 pi u): slopes 2 pi A cos(2 pi u)
    height = (torch.sin(2 * math.pi * u) * 0.5 + 0.5).expand(n, n)
    normal = normals_from_height(height, 2 * amplitude)
    ts = TextureSet(color=torch.full((n, n, 3), 0.5), normal=normal, roughness=torch.full((n, n), 0.5),
                    metalness=torch.zeros(n, n), height=height)
    stats = texture_statistics(ts, footprints=())
    slope = 2 * math.pi * amplitude * torch.cos(2 * math.pi * u) * math.sin(2 * math.pi / n) / (2 * math.pi / n)
    expected = torch.rad2deg(torch.atan(slope.abs())).mean()
    assert stats["tilt_deg"] == pytest.approx(float(expected), rel=1e-4)
    assert stats["roughness_std"] == 0 and stats["separability_rank"] == {}


def test_noise_corrected_rank_of_matrices_of_known_rank():
    g = torch.Generator().manual_seed(0)
    p, d = 200, 24

    def noisy(signal, sigma):
        return (signal + sigma * torch.randn(p, d, generator=g, dtype=torch.float64),
                signal + sigma * torch.randn(p, d, generator=g, dtype=torch.float64))

    column = torch.randn(1, d, generator=g, dtype=torch.float64) * 5   # per-direction means: removed
    factors = [torch.randn(p, 1, generator=g, dtype=torch.float64) @ torch.randn(1, d, generator=g,
                                                                                dtype=torch.float64)
               for _ in range(3)]
    assert noise_corrected_rank(*noisy(column.expand(p, d), 0.01)) == 0          # no spatial variation
    assert noise_corrected_rank(*noisy(column + factors[0], 0.01)) == 1          # separable
    assert noise_corrected_rank(*noisy(column + factors[0] + 0.7 * factors[1] + 0.5 * factors[2], 0.01)) == 3
    assert noise_corrected_rank(*noisy(column + 1e-3 * factors[0], 0.1)) == 0    # buried in the noise


def test_separability_rank_of_a_uniform_set_is_zero_and_of_a_detail_set_is_not():
    n = 16
    flat = TextureSet(color=torch.full((n, n, 3), 0.4), normal=torch.tensor([0.0, 0.0, 1.0]).expand(n, n, 3).clone(),
                      roughness=torch.full((n, n), 0.4), metalness=torch.zeros(n, n), height=torch.zeros(n, n))
    assert separability_rank(flat, 1, pairs=8, samples=4) == 0
    assert separability_rank(detail_texture_set("scratches", n), 1, pairs=16, samples=4) >= 2
    with pytest.raises(InputError, match="energy"):
        separability_rank(flat, 1, energy=1.5)
