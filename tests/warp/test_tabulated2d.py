"""Tabulated2D: exact density, round trips, zero cells, chi-square, speed on env-map sized tables."""
import time

import pytest
import torch

from neumat import InputError
from neumat.testing.chi2 import chi2_2d
from neumat.warp import Tabulated2D


def _table(h=8, w=16, seed=0):
    g = torch.Generator().manual_seed(seed)
    v = torch.rand(h, w, generator=g, dtype=torch.float64) ** 3
    v[2] = 0  # an empty row
    v[:, 5] = 0  # an empty column
    return v


def test_pdf_is_normalised_table_and_integrates_to_one():
    v = _table()
    t = Tabulated2D(v)
    h, w = v.shape
    ys, xs = torch.meshgrid((torch.arange(h) + 0.5) / h, (torch.arange(w) + 0.5) / w, indexing="ij")
    p = torch.stack([xs.reshape(-1), ys.reshape(-1)], -1).double()
    dens = t.pdf(p).reshape(h, w)
    torch.testing.assert_close(dens, v * (h * w) / v.sum())
    assert abs(dens.mean().item() - 1) < 1e-12  # midpoint rule is exact for a piecewise constant pdf
    assert t.pdf(torch.tensor([[1.2, 0.5], [0.5, -0.1]], dtype=torch.float64)).abs().sum() == 0


def test_sample_pdf_consistency_roundtrips_and_zero_cells():
    v = _table()
    t = Tabulated2D(v)
    u = torch.rand(20_000, 2, dtype=torch.float64)
    p, pdf = t.sample(u)
    assert p.dtype == torch.float64 and ((p >= 0) & (p <= 1)).all()
    torch.testing.assert_close(pdf, t.pdf(p))
    assert (pdf > 0).all()  # never lands in a zero cell
    torch.testing.assert_close(t.invert(p), u, atol=1e-10, rtol=0)
    torch.testing.assert_close(t.sample(t.invert(p))[0], p, atol=1e-10, rtol=0)
    # Jacobian: d p / d u has determinant 1 / pdf (the warp is triangular, so check numerically)
    h = 1e-7
    uu = u[:200].clamp(0.01, 0.99)
    d0 = (t.sample(uu + torch.tensor([h, 0.0], dtype=torch.float64))[0] - t.sample(uu)[0]) / h
    d1 = (t.sample(uu + torch.tensor([0.0, h], dtype=torch.float64))[0] - t.sample(uu)[0]) / h
    det = (d0[:, 0] * d1[:, 1] - d0[:, 1] * d1[:, 0]).abs()
    same_cell = (t.pdf(t.sample(uu + h)[0]) == t.pdf(t.sample(uu)[0]))
    torch.testing.assert_close((det * t.sample(uu)[1])[same_cell], torch.ones(int(same_cell.sum()),
                               dtype=torch.float64), rtol=1e-4, atol=0)


def test_chi2_cells_aligned_with_table():
    v = _table().float()
    t = Tabulated2D(v)
    r = chi2_2d(lambda u: t.sample(u)[0], t.pdf, n_samples=100_000, res=(16, 8))
    assert r, r.message
    assert abs(r.pdf_integral - 1) < 1e-5


def test_float32_dtype_and_env_map_speed():
    t = Tabulated2D(torch.rand(512, 1024) ** 4)
    u = torch.rand(1_000_000, 2)
    start = time.perf_counter()
    p, pdf = t.sample(u)
    elapsed = time.perf_counter() - start
    assert p.dtype == torch.float32 and pdf.dtype == torch.float32
    assert elapsed < 5.0, f"1M samples from a 1024x512 table took {elapsed:.2f} s"


@pytest.mark.parametrize("bad, match", [
    (torch.tensor([[1.0, -1.0]]), "non-negative"),
    (torch.tensor([[1.0, float("nan")]]), "NaN"),
    (torch.zeros(3, 4), "all zeros"),
    (torch.ones(3), "shape"),
    (torch.ones(0, 4), "non-empty"),
])
def test_bad_tables(bad, match):
    with pytest.raises(InputError, match=match):
        Tabulated2D(bad)
