import math

import pytest
import torch

from neumat.core.errors import InputError
from neumat.nn.latent_texture import (LatentPyramid, bilinear, bilinear_maps, box_pyramid, check_footprint,
                                      filter_anisotropic, footprint_axes, isotropic_footprint, trilinear)


def _band_limited(size=64, seed=0):
    """Sum of random cosines up to 8 cycles per tile, amplitude falling with frequency (float64)."""
    g = torch.Generator().manual_seed(seed)
    yy, xx = torch.meshgrid(torch.arange(size, dtype=torch.float64) + 0.5,
                            torch.arange(size, dtype=torch.float64) + 0.5, indexing="ij")
    tex = torch.zeros(3, size, size, dtype=torch.float64)
    for _ in range(40):
        fx, fy = torch.randint(-8, 9, (2,), generator=g).tolist()
        phase = torch.rand(3, 1, 1, generator=g, dtype=torch.float64) * 2 * math.pi
        amp = torch.randn(3, 1, 1, generator=g, dtype=torch.float64) / (1 + math.hypot(fx, fy))
        tex += amp * torch.cos(2 * math.pi * (fx * xx + fy * yy) / size + phase)
    return tex


def _covariances(n, sigma, elongation, g):
    theta = torch.rand(n, generator=g, dtype=torch.float64) * math.pi
    c, s = torch.cos(theta), torch.sin(theta)
    rot = torch.stack([torch.stack([c, -s], -1), torch.stack([s, c], -1)], -2)
    d = torch.diag_embed(torch.tensor([[sigma ** 2 * elongation ** 2, sigma ** 2]], dtype=torch.float64).expand(n, 2))
    return rot @ d @ rot.transpose(1, 2)


def _monte_carlo(tex, uv, cov, k, g):
    chol = torch.linalg.cholesky(cov)
    z = torch.randn(uv.shape[0], k, 2, generator=g, dtype=torch.float64)
    pts = uv[:, None] + torch.einsum("nij,nkj->nki", chol, z)
    return bilinear(tex, pts.reshape(-1, 2)).reshape(uv.shape[0], k, -1).mean(1)


def test_bilinear_texel_centres_orientation_and_wrap():
    tex = torch.arange(12, dtype=torch.float64).reshape(1, 3, 4)
    # texel (row i, col j) has its centre at uv = ((j + 0.5) / W, 1 - (i + 0.5) / H)
    uv = torch.tensor([[0.5 / 4, 1 - 0.5 / 3], [2.5 / 4, 1 - 1.5 / 3], [3.5 / 4 + 0.125, 1 - 2.5 / 3]],
                      dtype=torch.float64)
    torch.testing.assert_close(bilinear(tex, uv)[:, 0], torch.tensor([0.0, 6.0, 0.5 * (11 + 8)], dtype=torch.float64))
    torch.testing.assert_close(bilinear(tex, uv + 1), bilinear(tex, uv))


@pytest.mark.parametrize("sigma_texels, elongation", [(0.25, 1), (0.25, 20), (1, 4), (2, 1), (4, 20), (8, 4),
                                                      (32, 1)])
def test_anisotropic_filter_matches_monte_carlo_footprint_average(sigma_texels, elongation):
    """Against the Monte Carlo average of 4096 bilinear lookups over the Gaussian footprint: RMS error
    below 15 % of the texture's standard deviation (measured 1-12 %: the box pyramid and the tent only match
    the Gaussian's second moments), and for elongated footprints far below isotropic filtering at the major
    axis."""
    tex = _band_limited()
    g = torch.Generator().manual_seed(1)
    n = 64
    uv = torch.rand(n, 2, generator=g, dtype=torch.float64)
    cov = _covariances(n, sigma_texels / 64, elongation, g)
    ref = _monte_carlo(tex, uv, cov, 4096, g)
    levels = box_pyramid(tex)
    got = filter_anisotropic(levels, uv, cov)
    err = (got - ref).square().mean().sqrt() / tex.std()
    print(f"sigma {sigma_texels} texels, elongation {elongation}: relative RMS error {err:.4f}")
    assert err < 0.15
    if elongation >= 4 and sigma_texels * elongation <= 16:
        major, _, _ = footprint_axes(cov * 64 ** 2)
        iso = trilinear(levels, uv, torch.log2(2 * major))
        assert err < 0.5 * (iso - ref).square().mean().sqrt() / tex.std()


def test_huge_footprint_is_the_texture_mean_and_tiny_one_is_bilinear():
    tex = _band_limited(seed=2)
    levels = box_pyramid(tex)
    uv = torch.rand(16, 2, dtype=torch.float64)
    big = torch.eye(2, dtype=torch.float64).expand(16, 2, 2) * 10.0
    torch.testing.assert_close(filter_anisotropic(levels, uv, big), tex.mean((1, 2)).expand(16, 3))
    tiny = torch.eye(2, dtype=torch.float64).expand(16, 2, 2) * 1e-12
    torch.testing.assert_close(filter_anisotropic(levels, uv, tiny), bilinear(tex, uv))


def test_pyramid_module_is_differentiable_and_consistent():
    torch.manual_seed(0)
    pyr = LatentPyramid(4, 16).double()
    uv = torch.rand(32, 2, dtype=torch.float64)
    lod = torch.rand(32, dtype=torch.float64) * 4
    a = pyr(uv, lod=lod)
    b = pyr(uv, footprint=isotropic_footprint(lod, 16))
    torch.testing.assert_close(a, b)
    cov = _covariances(32, 2 / 16, 6, torch.Generator().manual_seed(3))
    (pyr(uv, footprint=cov).sum() + a.sum()).backward()
    for level in pyr.raw:  # 16 .. 1 texels: lods 0 .. 4 are all reached
        assert level.grad is not None and bool(torch.isfinite(level.grad).all()) and level.grad.abs().sum() > 0


def test_bad_footprints_and_sizes_raise():
    with pytest.raises(InputError, match=r"footprint\[1\]: expected a positive definite"):
        check_footprint(torch.tensor([[[1.0, 0.0], [0.0, 1.0]], [[1.0, 2.0], [2.0, 1.0]]]))
    with pytest.raises(InputError, match="symmetric"):
        check_footprint(torch.tensor([[[1.0, 0.5], [0.0, 1.0]]]))
    with pytest.raises(InputError, match="non-finite"):
        check_footprint(torch.tensor([[[float("nan"), 0.0], [0.0, 1.0]]]))
    with pytest.raises(InputError, match="shape"):
        check_footprint(torch.ones(3, 2))
    with pytest.raises(InputError, match="power of two"):
        LatentPyramid(4, 12)


def test_atlas_lookups_equal_level_by_level_bilinear_reads():
    """trilinear / filter_anisotropic (one grid_sample over the padded-level atlas) equal blends of `bilinear`
    reads of each level, for a non-square pyramid, with uv outside [0, 1]^2 and lods beyond the pyramid."""
    g = torch.Generator().manual_seed(7)
    levels = [l.requires_grad_() for l in box_pyramid(torch.randn(3, 12, 20, dtype=torch.float64, generator=g))]
    uv = torch.rand(400, 2, dtype=torch.float64, generator=g) * 3 - 1
    lod = torch.rand(400, dtype=torch.float64, generator=g) * 7 - 1
    c = lod.clamp(0, len(levels) - 1)
    lo = c.floor().long()
    t = (c - lo).unsqueeze(-1)
    reads = torch.stack([bilinear(tex, uv) for tex in levels])  # (L, N, C)
    rows = torch.arange(400)
    ref = (1 - t) * reads[lo, rows] + t * reads[(lo + 1).clamp(max=len(levels) - 1), rows]
    got = trilinear(levels, uv, lod)
    torch.testing.assert_close(got, ref, rtol=1e-12, atol=1e-12)
    for a, b in zip(torch.autograd.grad(got.square().sum(), levels), torch.autograd.grad(ref.square().sum(), levels)):
        torch.testing.assert_close(a, b, rtol=1e-12, atol=1e-12)
    tiny = _covariances(400, 1e-6, 1.0, g)
    torch.testing.assert_close(filter_anisotropic(levels, uv, tiny), bilinear(levels[0], uv))
    empty = uv[:0]
    assert filter_anisotropic(levels, empty, tiny[:0]).shape == (0, 3)
    assert trilinear(levels, empty, lod[:0]).shape == (0, 3)


def test_build_atlas_matches_the_gathered_atlas_values_and_gradients():
    """`build_atlas` (padded copies) holds the texels of the `flat_levels` gather on every used atlas texel, and
    the pyramid's filtered and trilinear lookups through it equal those through the gather, values and gradients
    (float64, preconditioned pyramid)."""
    from neumat.nn.latent_texture import LatentPyramid, atlas_layout, build_atlas, filter_anisotropic, trilinear_flat
    from neumat.nn.preconditioner import FrequencyPreconditioner, flat_levels

    g = torch.Generator().manual_seed(5)
    levels = [torch.randn(3, 16 >> l, 16 >> l, dtype=torch.float64, generator=g) for l in range(5)]
    sizes = tuple(tuple(t.shape[1:]) for t in levels)
    layout = atlas_layout(sizes, torch.device("cpu"))
    width, height = (int(v) for v in layout["shape"])
    gathered = flat_levels(levels).index_select(1, layout["source"]).view(3, height, width)
    built = build_atlas(levels)[0]
    used = torch.zeros(height, width, dtype=torch.bool)
    for (h, w), (left, top) in zip(sizes, layout["origin"].long().tolist()):
        used[top - 1:top + h + 1, left - 1:left + w + 1] = True
    assert torch.equal(built[:, used], gathered[:, used])

    pyramid = LatentPyramid(3, 16, precondition=FrequencyPreconditioner(10.0)).double()
    n = 64
    uv = torch.rand(n, 2, generator=g, dtype=torch.float64) * 3 - 1
    cov = torch.diag_embed(torch.rand(n, 2, generator=g, dtype=torch.float64) * 1e-2 + 1e-5)
    lod = torch.rand(n, generator=g, dtype=torch.float64) * 5 - 0.5
    weight = torch.randn(n, 3, generator=g, dtype=torch.float64)
    for new, old in ((lambda: pyramid(uv, cov),
                      lambda: filter_anisotropic(list(pyramid.raw), uv, cov, pyramid.max_probes, flat=pyramid.flat())),
                     (lambda: pyramid(uv, lod=lod),
                      lambda: trilinear_flat(pyramid.flat(), [t.shape[1:] for t in pyramid.raw], uv, lod))):
        got = new()
        grads = torch.autograd.grad((got * weight).sum(), list(pyramid.raw))
        want = old()
        wants = torch.autograd.grad((want * weight).sum(), list(pyramid.raw))
        torch.testing.assert_close(got, want, rtol=1e-12, atol=1e-12)
        for a, b in zip(grads, wants):
            torch.testing.assert_close(a, b, rtol=1e-10, atol=1e-12)


def test_bilinear_maps_equals_bilinear_and_keeps_its_padded_copy_until_the_maps_change():
    class Owner:
        pass
    owner, g = Owner(), torch.Generator().manual_seed(3)
    maps = torch.rand(5, 33, 17, generator=g)
    for dtype in (torch.float32, torch.float64):
        uv = torch.rand(4000, 2, generator=g, dtype=dtype) * 3 - 1  # outside [0, 1)^2 too: wrap tiling
        assert torch.equal(bilinear_maps(owner, maps, uv), bilinear(maps.to(dtype), uv))
    kept = dict(owner._derived_tensors)
    assert len(kept) == 2  # one per dtype
    bilinear_maps(owner, maps, uv)
    bilinear_maps(owner, maps, uv.float())
    assert all(owner._derived_tensors[k][1] is kept[k][1] for k in kept)  # reused, not rebuilt
    step = torch.nn.Parameter(torch.zeros(1))  # a training step on a model's parameters leaves a source's maps kept
    step.grad = torch.ones(1)
    torch.optim.SGD([step], lr=1.0).step()
    bilinear_maps(owner, maps, uv)
    assert all(owner._derived_tensors[k][1] is kept[k][1] for k in kept)
    maps.mul_(2)  # an in-place change is seen
    assert torch.equal(bilinear_maps(owner, maps, uv), bilinear(maps.to(torch.float64), uv))
    leaf = maps.clone().requires_grad_()  # maps that want a gradient are looked up directly, with autograd
    bilinear_maps(owner, leaf, uv.float()).sum().backward()
    assert leaf.grad is not None and leaf.grad.abs().sum() > 0


def test_training_steps_reuse_the_atlas_and_learn_the_same():
    """The first atlas of each training step is written into the last step's (no 50 MB allocation per 1K step):
    the same losses and gradients as atlases built anew, a second lookup in one step gets its own atlas, and a graph
    whose atlas a later step overwrote fails loudly at its backward instead of giving wrong gradients."""
    torch.manual_seed(0)
    uv, lod = torch.rand(64, 2), torch.rand(64) * 4
    kept, fresh = LatentPyramid(4, 16), LatentPyramid(4, 16)
    fresh.load_state_dict(kept.state_dict())
    opts = [torch.optim.Adam(m.parameters(), lr=0.1) for m in (kept, fresh)]
    stores = []
    for _ in range(3):
        losses = []
        for m, opt in zip((kept, fresh), opts):
            if m is fresh:
                m.__dict__.pop("_atlas_stamp", None)  # never reuses: every atlas new
                m.__dict__.pop("_atlas_store", None)
            opt.zero_grad()
            loss = (m(uv, lod=lod) ** 2).sum() + m(uv * 0.5, lod=lod).sum()  # two lookups in one step
            loss.backward()
            losses.append(loss.item())
            opt.step()
        assert losses[0] == losses[1]
        for a, b in zip(kept.raw, fresh.raw):
            torch.testing.assert_close(a.grad, b.grad, rtol=0, atol=0)
        stores.append(kept._atlas_store[0].data_ptr())
    assert len(set(stores)) == 1  # one atlas buffer for every step
    old = kept(uv, lod=lod).sum()
    opts[0].step()  # an optimiser step, then the next step's lookup overwrites the atlas that `old` reads
    kept(uv, lod=lod).sum()
    with pytest.raises(RuntimeError, match="modified"):
        old.backward()
