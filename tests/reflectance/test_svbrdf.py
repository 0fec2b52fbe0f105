import math

import pytest
import torch

from neumat.core.errors import InputError
from neumat.core.query import Query
from neumat.io.texture_set import TextureSet
from neumat.reflectance.microfacet import principled_eval
from neumat.reflectance.svbrdf import SVBRDF
from neumat.testing.chi2 import chi2_material
from neumat.warp.hemisphere import sample_cosine_hemisphere


def _constant_set(h=4, w=4, normal=(0.0, 0.0, 1.0), color=(0.6, 0.3, 0.1), roughness=0.4, metal=0.0):
    n = torch.tensor(normal, dtype=torch.float32)
    return TextureSet(color=torch.tensor(color).expand(h, w, 3).clone(), normal=(n / n.norm()).expand(h, w, 3).clone(),
                      roughness=torch.full((h, w), roughness), metalness=torch.full((h, w), metal),
                      height=torch.zeros(h, w), name="constant")


def _checker_set(size=8):
    ij = torch.arange(size)
    odd = ((ij[:, None] + ij[None, :]) % 2).float()
    color = torch.stack([0.8 * odd + 0.1, 0.2 + 0 * odd, 0.5 - 0.4 * odd], -1)
    tilt = torch.stack([0.3 * (2 * odd - 1), 0.1 + 0 * odd, torch.ones_like(odd)], -1)
    return TextureSet(color=color, normal=tilt / tilt.norm(dim=-1, keepdim=True), roughness=0.15 + 0.6 * odd,
                      metalness=odd, height=torch.zeros(size, size), name="checker")


def _directions(n, seed=0, dtype=torch.float32):
    g = torch.Generator().manual_seed(seed)
    return (sample_cosine_hemisphere(torch.rand(n, 2, generator=g, dtype=dtype)),
            sample_cosine_hemisphere(torch.rand(n, 2, generator=g, dtype=dtype)),
            torch.rand(n, 2, generator=g, dtype=dtype))


def test_flat_constant_maps_give_the_principled_brdf():
    wi, wo, uv = _directions(500)
    m = SVBRDF(_constant_set())
    ref = principled_eval(wi, wo, torch.tensor([0.6, 0.3, 0.1]), 0.0, 0.4, 0.0)
    torch.testing.assert_close(m.eval(Query(wi, wo, uv=uv)), ref, rtol=1e-5, atol=1e-6)


def test_tilted_normal_matches_rotated_frame_reference():
    """Reference in float64: rotate the directions so the shading normal becomes +z (Rodrigues), keep the
    tangent in the plane spanned by +x and the normal, scale by the symmetrised cosine ratio."""
    wi, wo, uv = _directions(800, seed=1, dtype=torch.float64)
    n = torch.tensor([0.35, -0.2, 0.9], dtype=torch.float64)
    n = n / n.norm()
    t = torch.tensor([1.0, 0, 0], dtype=torch.float64) - n[0] * n
    t = t / t.norm()
    b = torch.linalg.cross(n, t)
    basis = torch.stack([t, b, n])  # rows: local axes in geometric coordinates
    li, lo = wi @ basis.T, wo @ basis.T
    f = principled_eval(li, lo, torch.tensor([0.6, 0.3, 0.1], dtype=torch.float64), 0.0, 0.4, 0.0)
    ratio = 0.5 * (li[:, 2] / wi[:, 2] + lo[:, 2] / wo[:, 2])
    ok = (li[:, 2] > 0) & (lo[:, 2] > 0)
    ref = torch.where(ok[:, None], f * ratio[:, None], torch.zeros_like(f))
    m = SVBRDF(_constant_set(normal=tuple(n.tolist())))
    got = m.eval(Query(wi.float(), wo.float(), uv=uv.float()))
    torch.testing.assert_close(got, ref.float(), rtol=2e-4, atol=1e-5)
    assert bool((got[~ok] == 0).all()) and int((~ok).sum()) > 0


def test_constant_maps_are_unchanged_by_filtering():
    wi, wo, uv = _directions(64)
    m = SVBRDF(_constant_set(normal=(0.2, 0.1, 1.0)), samples=32)
    cov = torch.tensor([[1e-3, 4e-4], [4e-4, 5e-4]]).expand(64, 2, 2).contiguous()
    torch.testing.assert_close(m.eval(Query(wi, wo, uv=uv, footprint=cov)), m.eval(Query(wi, wo, uv=uv)),
                               rtol=1e-5, atol=1e-6)


def test_wide_footprint_converges_to_texture_average():
    """A footprint covering many periods is a uniform average over the tile: compare the Monte Carlo
    estimate (4096 samples) with a 128^2 midpoint-rule average of the point values, within 4 standard errors."""
    wi, wo, _ = _directions(6, seed=2)
    m = SVBRDF(_checker_set(), samples=4096, seed=3)
    cov = torch.eye(2).expand(6, 2, 2) * 3.0 ** 2
    uv = torch.full((6, 2), 0.37)
    est = m.eval(Query(wi, wo, uv=uv, footprint=cov.contiguous()))
    g = (torch.arange(128) + 0.5) / 128
    grid = torch.stack(torch.meshgrid(g, g, indexing="xy"), -1).reshape(-1, 2)
    for k in range(6):
        vals = m.eval_point(wi[k:k + 1].expand(len(grid), 3), wo[k:k + 1].expand(len(grid), 3), grid)
        stderr = vals.std(0) / math.sqrt(4096)
        assert bool(((est[k] - vals.mean(0)).abs() <= 4 * stderr + 1e-6).all()), (est[k], vals.mean(0), stderr)


def test_tiny_footprint_is_the_point_value():
    wi, wo, uv = _directions(64, seed=4)
    m = SVBRDF(_checker_set(), samples=16)
    cov = torch.eye(2).expand(64, 2, 2) * 1e-7 ** 2
    torch.testing.assert_close(m.eval(Query(wi, wo, uv=uv, footprint=cov.contiguous())),
                               m.eval(Query(wi, wo, uv=uv)), rtol=1e-3, atol=1e-5)


def test_filtered_value_is_reciprocal():
    wi, wo, uv = _directions(128, seed=5)
    cov = (torch.eye(2) * 0.05 ** 2).expand(128, 2, 2).contiguous()
    q = Query(wi, wo, uv=uv, footprint=cov)
    a = SVBRDF(_checker_set(), samples=64, seed=7).eval(q)
    b = SVBRDF(_checker_set(), samples=64, seed=7).eval(q.swapped())
    torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-6)


def test_lod_means_the_isotropic_footprint():
    wi, wo, uv = _directions(32, seed=6)
    lod = torch.full((32,), 2.0)
    cov = (torch.eye(2) * (4 / 2 / 8) ** 2).expand(32, 2, 2).contiguous()  # 2^lod / 2 texels of 8
    a = SVBRDF(_checker_set(), samples=32, seed=1).eval(Query(wi, wo, uv=uv, lod=lod))
    b = SVBRDF(_checker_set(), samples=32, seed=1).eval(Query(wi, wo, uv=uv, footprint=cov))
    torch.testing.assert_close(a, b)


@pytest.mark.parametrize("wi, uv", [
    ((0.3, 0.2, 0.932738), (0.3, 0.6)),
    pytest.param((-0.7, 0.1, 0.707107), (0.55, 0.55), marks=pytest.mark.slow),
    pytest.param((0.9, 0.0, 0.43589), (0.1, 0.8), marks=pytest.mark.slow),
])
def test_sampling_matches_pdf(wi, uv):
    wi = torch.tensor(wi)
    wi = wi / wi.norm()
    m = SVBRDF(_checker_set())
    result = chi2_material(m, wi, n_samples=100_000, res=(40, 40), template=Query(wi[None], uv=torch.tensor([uv])))
    assert result, result.message


def test_sample_weight_is_eval_cos_over_pdf():
    wi, _, uv = _directions(256, seed=8)
    m = SVBRDF(_checker_set())
    s = m.sample(Query(wi, uv=uv), torch.rand(256, 2, generator=torch.Generator().manual_seed(0)))
    ok = s.pdf > 0
    ref = m.eval(Query(wi, s.wo, uv=uv))[ok] * (s.wo[ok, 2] / s.pdf[ok])[:, None]
    torch.testing.assert_close(s.weight[ok], ref)


def test_bad_queries_raise():
    wi, wo, uv = _directions(4)
    m = SVBRDF(_checker_set(), samples=4)
    with pytest.raises(InputError, match="Query.uv"):
        m.eval(Query(wi, wo))
    bad = torch.tensor([[1e-4, 2e-4], [2e-4, 1e-4]]).expand(4, 2, 2).contiguous()
    with pytest.raises(InputError, match="positive definite"):
        m.eval(Query(wi, wo, uv=uv, footprint=bad))
    asym = torch.tensor([[1e-4, 2e-5], [0.0, 1e-4]]).expand(4, 2, 2).contiguous()
    with pytest.raises(InputError, match="symmetric"):
        m.eval(Query(wi, wo, uv=uv, footprint=asym))
    with pytest.raises(InputError, match="samples"):
        SVBRDF(_checker_set(), samples=0)


def test_real_texture_set(shared_data):
    m = SVBRDF.from_folder(shared_data / "svbrdf" / "Metal027_1K", max_size=32, samples=16)
    wi, wo, uv = _directions(256, seed=9)
    cov = (torch.eye(2) * 0.01 ** 2).expand(256, 2, 2).contiguous()
    f = m.eval(Query(wi, wo, uv=uv, footprint=cov))
    assert f.shape == (256, 3) and bool(torch.isfinite(f).all()) and bool((f >= 0).all()) and f.max() > 0
    assert "Metal027_1K" in m.describe()
