"""HEALPix in torch against healpy, and the NeuBRDF hemisphere-grid layout."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from neumat.core.errors import InputError
from neumat.nn import healpix as hpx

hp = pytest.importorskip("healpy")

NSIDES = [1, 2, 8, 64]


def _dirs(n: int, seed: int = 0) -> np.ndarray:
    v = np.random.default_rng(seed).normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


@pytest.mark.parametrize("nside", NSIDES + [3])
def test_vec2pix_ang2pix_equal_healpy(nside):
    v = _dirs(20000, nside)
    ref = hp.vec2pix(nside, *v.T)
    assert np.array_equal(hpx.vec2pix(nside, torch.from_numpy(v)).numpy(), ref)
    th, ph = hp.vec2ang(v)
    assert np.array_equal(hpx.ang2pix(nside, torch.from_numpy(th), torch.from_numpy(ph)).numpy(), ref)
    # float32 input: only directions within float32 rounding of a pixel boundary may differ
    p32 = hpx.vec2pix(nside, torch.from_numpy(v).float()).numpy()
    assert (p32 != ref).mean() < 1e-3


@pytest.mark.parametrize("nside", NSIDES)
def test_vec2pix_near_poles_and_equator(nside):
    eps = np.array([1e-9, 1e-6, 1e-3])
    th = np.concatenate([eps, math.pi - eps, math.pi / 2 + eps, math.pi / 2 - eps])
    ph = np.linspace(0.1, 6.2, th.size)
    ref = hp.ang2pix(nside, th, ph)
    assert np.array_equal(hpx.ang2pix(nside, torch.from_numpy(th), torch.from_numpy(ph)).numpy(), ref)


@pytest.mark.parametrize("nside", NSIDES)
def test_pix2ang_and_xyf(nside):
    pix = np.arange(12 * nside * nside)
    th, ph = hpx.pix2ang(nside, torch.from_numpy(pix))
    th_ref, ph_ref = hp.pix2ang(nside, pix)
    np.testing.assert_allclose(th.numpy(), th_ref, atol=1e-12)
    np.testing.assert_allclose(ph.numpy(), ph_ref, atol=1e-12)
    np.testing.assert_allclose(hpx.pix2vec(nside, torch.from_numpy(pix)).numpy(),
                               np.stack(hp.pix2vec(nside, pix), -1), atol=1e-12)
    x, y, f = hpx.pix2xyf(nside, torch.from_numpy(pix))
    xr, yr, fr = hp.pix2xyf(nside, pix)
    assert np.array_equal(x.numpy(), xr) and np.array_equal(y.numpy(), yr) and np.array_equal(f.numpy(), fr)


@pytest.mark.parametrize("nside", NSIDES)
def test_corners_match_boundaries(nside):
    pix = np.arange(12 * nside * nside)
    ref = hp.boundaries(nside, pix, step=1).transpose(0, 2, 1)  # (N, 4, 3), order N, W, S, E
    got = hpx.corners(nside, torch.from_numpy(pix), dtype=torch.float32).numpy()
    np.testing.assert_allclose(got, ref, atol=2e-7)


@pytest.mark.parametrize("nside", NSIDES + [3])
def test_vertex_ids_unique_and_complete(nside):
    pix = torch.arange(12 * nside * nside)
    vid = hpx.corner_vertices(nside, pix)
    assert torch.unique(vid).numel() == hpx.nvertices(nside) == 12 * nside * nside + 2
    # a vertex id always maps to the same point, whichever pixel it comes from
    pos = hpx.corners(nside, pix)
    table = hpx.vertex2vec(nside, vid)
    torch.testing.assert_close(pos, table, atol=1e-12, rtol=0)
    # ids are ordered ring by ring from the north pole
    z = hpx.vertex2vec(nside, torch.arange(hpx.nvertices(nside)))[:, 2]
    assert bool((z[1:] <= z[:-1] + 1e-12).all())


@pytest.mark.parametrize("nside", NSIDES)
def test_ring_nest_parent(nside):
    pix = np.arange(12 * nside * nside)
    assert np.array_equal(hpx.ring2nest(nside, torch.from_numpy(pix)).numpy(), hp.ring2nest(nside, pix))
    assert np.array_equal(hpx.nest2ring(nside, torch.from_numpy(pix)).numpy(), hp.nest2ring(nside, pix))
    if nside > 1:
        ref = hp.nest2ring(nside // 2, hp.ring2nest(nside, pix) >> 2)
        assert np.array_equal(hpx.parent(nside, torch.from_numpy(pix)).numpy(), ref)
        # the parent's corners, as fine vertices, sit where healpy puts the coarse corners
        got = hpx.vertex2vec(nside, hpx.ancestor_corner_vertices(nside, torch.from_numpy(pix), 1)).numpy()
        np.testing.assert_allclose(got, hp.boundaries(nside // 2, ref, step=1).transpose(0, 2, 1), atol=1e-12)


@pytest.mark.parametrize("nside", NSIDES)
def test_hemisphere_grids(nside):
    n = hpx.hemisphere_size(nside)
    assert n == 6 * nside ** 2 + 6 * nside + 1
    # paper footnote: the hemisphere without the equator has 6 N^2 - 2 N + 1 points
    z = hpx.vertex2vec(nside, torch.arange(hpx.nvertices(nside)))[:, 2]
    assert int((z > 1e-12).sum()) == 6 * nside ** 2 - 2 * nside + 1
    assert 2 * n == 12 * nside ** 2 + 12 * nside + 2
    # every upper-hemisphere direction (equator included) has its corners on S+ / S- (mirrored)
    v = torch.from_numpy(_dirs(20000, 5))
    v[:, 2] = v[:, 2].abs()
    v[:100, 2] = 0
    v[:100] /= v[:100].norm(dim=-1, keepdim=True)
    slots, vid, d = hpx.grid_corners(nside, v, south=False)
    assert int(slots.max()) < n and torch.equal(slots, vid)
    slots, vid, d = hpx.grid_corners(nside, v, south=True)
    assert int(slots.min()) >= n and int(slots.max()) < 2 * n
    torch.testing.assert_close(d[:, 2], -v[:, 2])  # (pi - theta, phi)
    ids = hpx.grid_vertex_ids(nside)
    assert torch.equal(ids[slots], vid)
    # three rings (equator and its two neighbours) are duplicated in the merged grid
    assert ids.numel() - torch.unique(ids).numel() == 3 * 4 * nside


def test_idw_weights_closed_form():
    corners = hpx.corners(8, torch.tensor([100, 300]))
    w = corners.mean(1)
    w = w / w.norm(dim=-1, keepdim=True)
    wts = hpx.idw_weights(w, corners)
    d = torch.stack([torch.arccos((w * corners[:, k]).sum(-1).clamp(-1, 1)) for k in range(4)], -1)
    torch.testing.assert_close(wts, (1 / d) / (1 / d).sum(-1, keepdim=True), atol=1e-6, rtol=0)
    on_vertex = hpx.idw_weights(corners[:, 2], corners)
    assert bool((on_vertex[:, 2] > 0.999).all())


def test_pruning_helpers():
    nside = 8
    v = torch.tensor([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]], dtype=torch.float64)
    sup = hpx.supervised_pixels(nside, v)
    assert int(sup.sum()) == 2
    touched = hpx.touched_vertices(nside, v)
    assert int(touched.sum()) <= 8 and bool(touched[0])  # the north pole is a corner of its pixel
    level = hpx.pruned_levels(nside, sup)
    assert int(level[sup].max()) == 0
    # brute force with `parent`: the level is the first ancestor level holding a supervised pixel
    anc_all, anc_sup = torch.arange(12 * nside * nside), torch.nonzero(sup).squeeze(1)
    expect = torch.full_like(anc_all, -1)
    for lv, ns in enumerate((nside, nside // 2, nside // 4, nside // 8)):
        has = torch.isin(anc_all, anc_sup)
        expect = torch.where((expect < 0) & has, torch.full_like(expect, lv), expect)
        if ns > 1:
            anc_all, anc_sup = hpx.parent(ns, anc_all), hpx.parent(ns, anc_sup)
    expect = torch.where(expect < 0, torch.full_like(expect, 3), expect)
    assert torch.equal(level, expect)
    assert int(level.max()) == 3  # far from both directions, whole base pixels are used


def test_bad_input_raises():
    v = torch.tensor([[0.0, 0.0, 2.0]])
    with pytest.raises(InputError, match="unit length"):
        hpx.vec2pix(8, v)
    for bad in (0, -2, 2.0, True):
        with pytest.raises(InputError, match="nside"):
            hpx.vec2pix(bad, torch.tensor([[0.0, 0.0, 1.0]]))
    with pytest.raises(InputError, match="power of two"):
        hpx.ring2nest(3, torch.tensor([0]))
    with pytest.raises(InputError, match="pix"):
        hpx.corners(2, torch.tensor([48]))
    with pytest.raises(InputError, match="theta"):
        hpx.ang2pix(2, torch.tensor([4.0]), torch.tensor([0.0]))
    with pytest.raises(InputError, match="no parent"):
        hpx.parent(1, torch.tensor([0]))
    with pytest.raises(InputError, match="level"):
        hpx.ancestor_corner_vertices(4, torch.tensor([0]), 3)


def test_mirror_pixels_match_healpy(gen):
    nside = 8
    mirror = hpx.mirror_pixels(nside)
    assert torch.equal(mirror[mirror], torch.arange(12 * nside ** 2))
    v = torch.randn(5000, 3, generator=gen, dtype=torch.float64)
    v = v / v.norm(dim=-1, keepdim=True)
    pix = torch.from_numpy(hp.vec2pix(nside, *v.numpy().T))
    pix_mirrored = torch.from_numpy(hp.vec2pix(nside, v[:, 0].numpy(), v[:, 1].numpy(), -v[:, 2].numpy()))
    assert torch.equal(mirror[pix], pix_mirrored)


@pytest.mark.parametrize("south", [False, True])
def test_grid_level_cap(south):
    nside = 8
    cap = hpx.grid_level_cap(nside, south)
    h, v = hpx.hemisphere_size(nside), hpx.nvertices(nside)
    pix = torch.arange(hpx.npix(nside))
    z = hpx.pix2vec(nside, pix)[:, 2]
    on_hemisphere = z <= 1e-12 if south else z >= -1e-12
    assert bool((cap[on_hemisphere] >= 0).all()) and bool((cap[~on_hemisphere] == -1).all())
    for level in range(4):
        vid = hpx.ancestor_corner_vertices(nside, pix, level)
        on_grid = ((vid >= v - h) if south else (vid < h)).all(-1)
        assert torch.equal(on_grid, cap >= level)
    assert int(cap.max()) == 3 and int(cap[on_hemisphere].min()) == 0  # poles vs the equator ring


def test_shared_ancestor_levels_brute_force(gen):
    nside = 8
    sup = torch.rand(hpx.npix(nside), generator=gen) < 0.03
    levels = hpx.pruned_levels(nside, sup)
    mask = hpx.shared_ancestor_levels(nside, levels)
    pix = torch.arange(hpx.npix(nside))
    anc = pix.clone()
    for level in range(1, 4):
        anc = hpx.parent(nside >> (level - 1), anc)  # level-`level` ancestor at nside / 2^level
        for p in range(0, hpx.npix(nside), 7):
            want = bool(((levels == level) & (anc == anc[p])).any())
            assert bool((mask[p] >> level) & 1) == want


def test_check_levels_checks_every_call_and_the_level_cap_is_cached():
    """`check_levels` validates the tensor's current values on every call (an in-place change is seen: it once
    sat under `grid_level_cap`'s cache decorator, which keyed it on the tensor object), and `grid_level_cap`
    is computed once per (nside, south)."""
    levels = torch.zeros(12 * 4 * 4, dtype=torch.int8)
    assert hpx.check_levels(levels, 4, "levels") is levels
    levels[3] = 3  # above log2 4 = 2
    with pytest.raises(InputError, match=r"levels: expected integer pruning levels in \[0, 2\]"):
        hpx.check_levels(levels, 4, "levels")
    assert hpx.grid_level_cap(4, True) is hpx.grid_level_cap(4, True)
