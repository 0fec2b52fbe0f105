"""MERL tabulation: exact at cell centres, GGX and RGL materials reproduced away from grazing angles."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from neumat import InputError, Material, Query
from neumat.core.coords import io_to_rusinkiewicz, rusinkiewicz_to_io
from neumat.io.merl import MERL_DIMS, read_merl, write_merl
from neumat.reflectance.measured import MerlMaterial, RglMaterial
from neumat.reflectance.tabulate import merl_cell_centres, tabulate_merl


class _Ggx(Material):
    """Float64 reference: isotropic GGX (alpha), separable Smith G, Schlick Fresnel with RGB F0."""

    def __init__(self, alpha: float, f0=(0.9, 0.6, 0.3)) -> None:
        self.alpha, self.f0 = alpha, torch.tensor(f0, dtype=torch.float64)

    def eval(self, q: Query) -> torch.Tensor:
        wi, wo = q.wi.double(), q.wo.double()
        h = wi + wo
        h = h / h.norm(dim=-1, keepdim=True)
        a2 = self.alpha ** 2
        d = a2 / (math.pi * (h[:, 2] ** 2 * (a2 - 1) + 1) ** 2)

        def g1(w):
            c2 = w[:, 2] ** 2
            return 2 / (1 + torch.sqrt(1 + a2 * (1 - c2) / c2))

        f = self.f0 + (1 - self.f0) * (1 - (wi * h).sum(-1, keepdim=True)).clamp(min=0) ** 5
        val = f * (d * g1(wi) * g1(wo) / (4 * wi[:, 2] * wo[:, 2])).unsqueeze(-1)
        ok = (wi[:, 2] > 0) & (wo[:, 2] > 0)
        return torch.where(ok.unsqueeze(-1), val, torch.zeros_like(val)).to(q.dtype)


def _cap(n: int, gen: torch.Generator, max_deg: float) -> torch.Tensor:
    c = math.cos(math.radians(max_deg))
    ct = c + (1 - c) * torch.rand(n, generator=gen, dtype=torch.float64)
    ph = 2 * math.pi * torch.rand(n, generator=gen, dtype=torch.float64)
    st = (1 - ct * ct).sqrt()
    return torch.stack([st * ph.cos(), st * ph.sin(), ct], -1)


def _rel(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """|a - b| relative to |b| plus 1 % of the largest |b| (so near-zero values do not dominate)."""
    return (a - b).abs() / (b.abs() + 0.01 * b.abs().max())


@pytest.fixture(scope="module")
def ggx_table():
    return tabulate_merl(_Ggx(0.3))


def test_exact_at_cell_centres(ggx_table, gen):
    """A query at a cell centre (any phi_h: the material is isotropic) returns the material's value."""
    ggx = _Ggx(0.3)
    th, td, pd = merl_cell_centres()
    idx = torch.randint(0, th.shape[0], (3000,), generator=gen)
    phi_h = 2 * math.pi * torch.rand(3000, generator=gen, dtype=torch.float64)
    wi, wo = rusinkiewicz_to_io(th[idx], phi_h, td[idx], pd[idx])
    ok = (wi[:, 2] > 1e-3) & (wo[:, 2] > 1e-3)
    q = Query(wi[ok], wo[ok])
    torch.testing.assert_close(MerlMaterial(ggx_table).eval(q), ggx.eval(q), rtol=1e-9, atol=1e-12)
    below = (wi[:, 2] <= 0) | (wo[:, 2] <= 0)
    assert np.all(ggx_table.reshape(3, -1)[:, idx[below].numpy()] == -1)


def test_merl_table_round_trip():
    """Tabulating a MERL material gives back its table wherever the cell centre is above the surface."""
    table = np.random.default_rng(2).uniform(0, 3000, size=(3, *MERL_DIMS))
    again = tabulate_merl(MerlMaterial(table), batch=1 << 18)
    valid = again[0] != -1
    assert 0.7 < valid.mean() < 0.8 and np.all(again[:, ~valid] == -1)
    np.testing.assert_allclose(again[:, valid], table[:, valid], rtol=1e-12)


def test_ggx_reproduced_away_from_grazing(ggx_table, gen):
    """GGX alpha = 0.3, both directions within 70 degrees of the normal, 20000 random pairs.
    Measured: nearest median 0.7 %, p99 4.0 %, max 6.8 %; trilinear median 0.04 %, p99 0.11 %, max 0.19 %."""
    ggx = _Ggx(0.3)
    q = Query(_cap(20000, gen, 70), _cap(20000, gen, 70))
    ref = ggx.eval(q)
    near = _rel(MerlMaterial(ggx_table).eval(q), ref)
    tri = _rel(MerlMaterial(ggx_table, interpolate=True).eval(q), ref)
    assert near.median() < 0.015 and near.quantile(0.99) < 0.08
    assert tri.median() < 0.001 and tri.quantile(0.99) < 0.003 and tri.max() < 0.005


# a diffuse and a glossy file by default; the other three (2 s of tabulation each) are `slow`
RGL_NAMES = ["paper_white", "vch_golden_yellow"] + [
    pytest.param(n, marks=pytest.mark.slow) for n in ("cc_ibiza_sunset", "cc_iris_purple_gem", "colodur_napoli_4f")]


@pytest.mark.parametrize("name", RGL_NAMES)
def test_rgl_to_merl(shared_data, tmp_path, gen, name):
    """RGL file -> MERL file -> MerlMaterial agrees with the RGL evaluation (thetas < 70 degrees, 20000 pairs).

    Pairs with phi_d < pi are tabulated directly; the others read the reciprocal pair (wo, wi), so they
    are compared with the RGL value of the swapped query (the RGL data is not exactly reciprocal: ~1 %
    median, up to 12 %). MERL stores no negative values, so the reference is clamped at 0 (the glossy
    RGL files have small negative RGB values near their peaks).
    Measured (median / p99 / max of `_rel`), trilinear: worst file 0.09 % / 1.2 % / 7.6 %, paper_white
    0.02 % / 0.4 % / 2.6 %; nearest: worst 0.34 % / 7.0 % / 17 %, paper_white 0.12 % / 0.9 % / 8 %."""
    path = shared_data / "rgl" / f"{name}_rgb.bsdf"
    if not path.is_file():
        pytest.skip(f"{path} is absent")
    rgl = RglMaterial.from_file(path)
    out = tmp_path / f"{name}.binary"
    write_merl(out, tabulate_merl(rgl, batch=1 << 18))
    table = read_merl(out).table
    q = Query(_cap(20000, gen, 70), _cap(20000, gen, 70))
    phi_d = io_to_rusinkiewicz(q.wi, q.wo)[3]
    direct = (phi_d < math.pi).unsqueeze(-1)
    ref = torch.where(direct, rgl.eval(q), rgl.eval(q.swapped())).clamp(min=0)
    near = _rel(MerlMaterial(table).eval(q), ref)
    tri = _rel(MerlMaterial(table, interpolate=True).eval(q), ref)
    assert tri.median() < 0.002 and tri.quantile(0.99) < 0.02 and tri.max() < 0.12
    assert near.median() < 0.006 and near.quantile(0.99) < 0.1 and near.max() < 0.3


def test_bad_input():
    with pytest.raises(InputError, match="expected a neumat Material"):
        tabulate_merl(lambda q: q)
    with pytest.raises(InputError, match="batch"):
        tabulate_merl(_Ggx(0.3), batch=0)


def test_table_layout():
    th, td, pd = merl_cell_centres()
    n_h, n_d, n_p = MERL_DIMS
    assert th.shape == (n_h * n_d * n_p,)
    # table order: theta_h slowest, phi_d fastest
    assert th[n_d * n_p] > th[0] and td[n_p] > td[0] and pd[1] > pd[0]
    assert torch.allclose(th[:1], torch.tensor([(0.5 / 90) ** 2 * math.pi / 2], dtype=torch.float64))


def test_merl_table_mse_is_the_closed_form_between_two_lambertians():
    """Two Lambertians differ by (a - b) / pi on every valid cell: the table MSE is the channel mean of its
    square; a material against itself gives 0; negatives would be clamped, as in the table."""
    from neumat.reflectance.analytic import Lambert
    from neumat.reflectance.tabulate import merl_table_mse
    a, b = (0.2, 0.5, 0.9), (0.3, 0.1, 0.9)
    expected = sum(((x - y) / math.pi) ** 2 for x, y in zip(a, b)) / 3
    assert merl_table_mse(Lambert(a), Lambert(b)) == pytest.approx(expected, rel=1e-12)
    assert merl_table_mse(Lambert(a), Lambert(a)) == 0.0
    table = tabulate_merl(Lambert(b))  # a tabulated reference scores the same
    assert merl_table_mse(Lambert(a), table) == merl_table_mse(Lambert(a), Lambert(b))
    with pytest.raises(InputError, match="a tabulated reference must be a MERL table of shape"):
        merl_table_mse(Lambert(a), table[:, :10])
