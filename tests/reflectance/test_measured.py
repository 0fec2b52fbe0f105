"""Measured materials: MERL lookup against a port of BRDFRead.cpp, trilinear mode, RGL against Mitsuba 3,
and the RGL warps (Marginal2D) against their own densities."""
from __future__ import annotations

import math
import pickle

import numpy as np
import pytest
import torch
from scipy import stats

from neumat import InputError, Query
from neumat.io.merl import MERL_DIMS, MERL_SCALE
from neumat.reflectance.measured import Marginal2D, MerlMaterial, RglMaterial

from mitsuba_util import mitsuba_or_skip


def _hemisphere(n: int, gen: torch.Generator, max_deg: float = 90.0, dtype=torch.float64) -> torch.Tensor:
    """Uniform directions on the spherical cap theta <= max_deg."""
    c = math.cos(math.radians(max_deg))
    ct = c + (1 - c) * torch.rand(n, generator=gen, dtype=torch.float64)
    ph = 2 * math.pi * torch.rand(n, generator=gen, dtype=torch.float64)
    st = (1 - ct * ct).clamp(min=0).sqrt()
    return torch.stack([st * ph.cos(), st * ph.sin(), ct], -1).to(dtype)


# --- MERL -----------------------------------------------------------------------------------------

def _brdfread_lookup(table: np.ndarray, wi, wo) -> np.ndarray:
    """Scalar transcription of the MERL reference `lookup_brdf_val` (BRDFRead.cpp)."""
    def rotate(v, axis, angle):
        c, s = math.cos(angle), math.sin(angle)
        return v * c + axis * np.dot(axis, v) * (1 - c) + np.cross(axis, v) * s

    half = (wi + wo) / 2
    half = half / np.linalg.norm(half)
    theta_half, phi_half = math.acos(min(half[2], 1.0)), math.atan2(half[1], half[0])
    tmp = rotate(wi, np.array([0.0, 0, 1]), -phi_half)
    diff = rotate(tmp, np.array([0.0, 1, 0]), -theta_half)
    theta_diff, phi_diff = math.acos(max(min(diff[2], 1.0), -1.0)), math.atan2(diff[1], diff[0])
    i_h = 0 if theta_half <= 0 else min(max(int(math.sqrt(theta_half / (math.pi / 2) * 90 * 90)), 0), 89)
    i_d = min(max(int(theta_diff / (math.pi / 2) * 90), 0), 89)
    if phi_diff < 0:
        phi_diff += math.pi
    i_p = min(max(int(phi_diff / math.pi * 180), 0), 179)
    flat = table.reshape(-1)
    ind = i_p + i_d * 180 + i_h * 180 * 90
    n = 90 * 90 * 180
    return np.array([flat[ind] * MERL_SCALE[0], flat[ind + n] * MERL_SCALE[1], flat[ind + 2 * n] * MERL_SCALE[2]])


@pytest.fixture(scope="module")
def merl_table() -> np.ndarray:
    return np.random.default_rng(1).uniform(0, 3000, size=(3, *MERL_DIMS))


def test_merl_nearest_matches_reference_lookup(merl_table, gen):
    """Identical cells everywhere except where phi_d is undefined (wi == wo) or exactly pi (wi == n,
    where the reference's cell depends on the sign of a zero); these sets are excluded."""
    wi, wo = _hemisphere(1500, gen), _hemisphere(1500, gen)
    # include specular configurations (theta_h = 0) and theta_h just above 0
    wo[:50] = wi[:50] * torch.tensor([-1.0, -1, 1], dtype=torch.float64)
    wo[50:100] = wi[50:100] * torch.tensor([-1.0, -1, 1], dtype=torch.float64) + 1e-4 * wo[50:100]
    wo[50:100] = wo[50:100] / wo[50:100].norm(dim=-1, keepdim=True)
    ours = MerlMaterial(merl_table).eval(Query(wi, wo)).numpy()
    ref = np.stack([_brdfread_lookup(merl_table, a, b) for a, b in zip(wi.numpy(), wo.numpy())])
    assert np.array_equal(ours, ref)


def test_merl_missing_values_clamp_and_horizon(merl_table, gen):
    t = -np.ones((3, *MERL_DIMS))
    wi, wo = _hemisphere(200, gen), _hemisphere(200, gen)
    assert torch.all(MerlMaterial(t).eval(Query(wi, wo)) == 0)
    below = wo * torch.tensor([1.0, 1, -1], dtype=torch.float64)
    assert torch.all(MerlMaterial(merl_table).eval(Query(wi, below)) == 0)


def test_merl_trilinear_reproduces_linear_functions(gen):
    """Trilinear interpolation between cell centres is exact for a table linear in the cell index
    (interior of theta_h, theta_d; constant in phi_d)."""
    i, j, _ = np.meshgrid(*(np.arange(n, dtype=np.float64) for n in MERL_DIMS), indexing="ij")
    lin = 1000 + 7 * i + 3 * j
    table = np.stack([lin, 2 * lin, 3 * lin]) / np.array(MERL_SCALE)[:, None, None, None]
    m = MerlMaterial(table, interpolate=True)
    wi, wo = _hemisphere(3000, gen), _hemisphere(3000, gen)
    from neumat.core.coords import io_to_rusinkiewicz
    th, _, td, _ = io_to_rusinkiewicz(wi, wo)
    x_h = torch.sqrt(th / (math.pi / 2)) * 90 - 0.5
    x_d = td / (math.pi / 2) * 90 - 0.5
    inner = (x_h > 0) & (x_h < 89) & (x_d > 0) & (x_d < 89)
    expect = (1000 + 7 * x_h + 3 * x_d)[:, None] * torch.tensor([1.0, 2, 3], dtype=torch.float64)
    got = m.eval(Query(wi, wo))
    assert inner.sum() > 2500
    torch.testing.assert_close(got[inner], expect[inner], rtol=1e-12, atol=1e-9)
    # nearest uses the cell containing the point, at most half a cell from it along each axis
    near = MerlMaterial(table).eval(Query(wi, wo))
    assert torch.all((got - near).abs() <= (7 + 3) * 0.5 * torch.tensor([1.0, 2, 3]) + 1e-9)


def test_merl_dtype_and_bad_input(merl_table, gen):
    m = MerlMaterial(merl_table)
    q = Query(_hemisphere(10, gen, dtype=torch.float32), _hemisphere(10, gen, dtype=torch.float32))
    assert m.eval(q).dtype == torch.float32 and m.eval(q).shape == (10, 3)
    with pytest.raises(InputError, match="MerlMaterial needs Query.wo"):
        m.eval(Query(q.wi))
    with pytest.raises(InputError, match=r"expected shape \(3, 90, 90, 180\)"):
        MerlMaterial(np.zeros((3, 90, 90, 360)))


def test_merl_from_file(tmp_path, merl_table, gen):
    from neumat.io.merl import write_merl
    from neumat.catalog.open_material import open_material
    write_merl(tmp_path / "x.binary", merl_table)
    m = open_material(tmp_path / "x.binary")
    q = Query(_hemisphere(100, gen), _hemisphere(100, gen))
    assert isinstance(m, MerlMaterial) and m.name == "x"
    assert torch.equal(m.eval(q), MerlMaterial(merl_table).eval(q))


# --- Marginal2D (the RGL warps) -----------------------------------------------------------------------

@pytest.fixture(scope="module")
def warp() -> Marginal2D:
    rng = np.random.default_rng(5)
    data = rng.random((2, 3, 6, 5)) ** 2 + 0.05
    return Marginal2D(data, [np.array([0.0, 1.0]), np.array([0.0, 0.3, 1.0])])


def test_marginal2d_normalised_and_invertible(warp, gen):
    n = 20000
    params = [torch.full((n,), 0.4, dtype=torch.float64), torch.full((n,), 0.62, dtype=torch.float64)]
    pos = torch.rand(n, 2, generator=gen, dtype=torch.float64)
    mean = warp.eval(pos, params)[:, 0].mean().item()  # Monte Carlo integral over the unit square
    assert abs(mean - 1) < 4 * 0.6 / math.sqrt(n)
    u = torch.rand(n, 2, generator=gen, dtype=torch.float64)
    x, pdf = warp.sample(u, params)
    u2, pdf2 = warp.invert(x, params)
    # tables and CDFs are float32 (as in Mitsuba): the round trip holds to ~1e-5
    torch.testing.assert_close(u2, u, atol=2e-5, rtol=0)
    torch.testing.assert_close(pdf, warp.eval(x, params)[:, 0], atol=1e-5, rtol=1e-5)
    torch.testing.assert_close(pdf2, pdf, atol=1e-5, rtol=1e-5)


def test_marginal2d_samples_follow_density(warp, gen):
    """Chi-square of an 8 x 8 histogram of samples against the density integrated per cell."""
    n, k = 40000, 8
    params = [torch.full((n,), 0.8, dtype=torch.float64), torch.full((n,), 0.1, dtype=torch.float64)]
    x, _ = warp.sample(torch.rand(n, 2, generator=gen, dtype=torch.float64), params)
    hist = np.histogram2d(x[:, 0].numpy(), x[:, 1].numpy(), bins=k, range=[[0, 1], [0, 1]])[0]
    g = (torch.arange(k * 16, dtype=torch.float64) + 0.5) / (k * 16)
    gx, gy = torch.meshgrid(g, g, indexing="ij")
    pts = torch.stack([gx.reshape(-1), gy.reshape(-1)], -1)
    m = pts.shape[0]
    dens = warp.eval(pts, [p[:1].expand(m) for p in params])[:, 0].reshape(k, 16, k, 16).mean((1, 3)) / k ** 2
    expected = dens.numpy() * n
    chi2 = ((hist - expected) ** 2 / expected).sum()
    assert stats.chi2.sf(chi2, k * k - 1) > 1e-3


@pytest.mark.parametrize("sizes", [(2, 3), (1, 3), (4,)])
def test_marginal2d_eval_and_cdf_lookups_are_the_multilinear_interpolant(sizes, gen):
    """`eval` (one gather of every corner of every parameter slice, one-slice parameters skipped) equals the
    multilinear interpolant of the table over (parameters, y, x) (scipy, float64), with channels; `invert`'s
    CDF lookups agree with `sample` (round trip), also with a one-slice parameter."""
    from scipy.interpolate import RegularGridInterpolator

    rng = np.random.default_rng(7)
    h, w, k, n = 6, 5, 3, 4000
    data = rng.random((*sizes, k, h, w)) + 0.05
    values = [np.sort(rng.random(s)) * 2 for s in sizes]
    table = Marginal2D(data, values, normalize=False, channels=True, sampling=False)
    params = [torch.as_tensor(v.min() + (v.max() - v.min()) * rng.random(n)) for v in values]
    pos = torch.rand(n, 2, generator=gen, dtype=torch.float64)
    got = table.eval(pos, params)
    keep = [d for d, s in enumerate(sizes) if s > 1]  # scipy needs two points per axis
    grid = [values[d] for d in keep] + [np.linspace(0, 1, h), np.linspace(0, 1, w)]
    ref_data = np.moveaxis(data.reshape(*(s for s in sizes if s > 1), k, h, w), len(keep), -1)
    pts = np.stack([params[d].numpy() for d in keep] + [pos[:, 1].numpy(), pos[:, 0].numpy()], -1)
    ref = RegularGridInterpolator(grid, ref_data)(pts)
    np.testing.assert_allclose(got.numpy(), ref, rtol=2e-6, atol=0)  # float32 table
    warp = Marginal2D(data[..., 0, :, :], values)
    u = torch.rand(n, 2, generator=gen, dtype=torch.float64)
    x, _ = warp.sample(u, params)
    torch.testing.assert_close(warp.invert(x, params)[0], u, atol=2e-5, rtol=0)


# --- RGL ------------------------------------------------------------------------------------------------

@pytest.fixture
def rgl_files(shared_data):
    files = sorted((shared_data / "rgl").glob("*_rgb.bsdf"))
    if not files:
        pytest.skip("no RGL *_rgb.bsdf files in the shared data folder")
    return files


@pytest.mark.mitsuba
def test_rgl_matches_mitsuba_measured_plugin(rgl_files, gen):
    """eval (BRDF * cos), pdf and sample of every shared file against Mitsuba 3 `measured` (llvm_ad_rgb,
    float32) at 3000 random pairs. Tolerance: |ours - mitsuba| <= 1e-3 * (|mitsuba| + 1e-3 max|mitsuba|)
    (measured worst case 9e-5); sampled directions within 1e-3 (measured 7e-5), their pdf within 2e-3
    relative (measured 2.4e-4)."""
    mi = mitsuba_or_skip()
    n = 3000
    for path in rgl_files:
        wi, wo = _hemisphere(n, gen), _hemisphere(n, gen)
        u = torch.rand(n, 2, generator=gen, dtype=torch.float64)
        bsdf = mi.load_dict({"type": "measured", "filename": str(path)})
        si = mi.SurfaceInteraction3f()
        si.wi = mi.Vector3f(wi.T.float().numpy())
        ctx = mi.BSDFContext()
        mwo = mi.Vector3f(wo.T.float().numpy())
        ref = torch.from_numpy(np.array(bsdf.eval(ctx, si, mwo)).T).double()
        ref_pdf = torch.from_numpy(np.array(bsdf.pdf(ctx, si, mwo))).double()
        bs, _ = bsdf.sample(ctx, si, mi.Float(np.zeros(n, np.float32)), mi.Point2f(u.T.float().numpy()))
        ref_wo = torch.from_numpy(np.array(bs.wo).T).double()
        ref_spdf = torch.from_numpy(np.array(bs.pdf)).double()

        m = RglMaterial.from_file(path)
        q = Query(wi, wo)
        for ours, theirs in ((m.eval_cos(q), ref), (m.pdf(q), ref_pdf)):
            tol = 1e-3 * (theirs.abs() + 1e-3 * theirs.abs().max())
            assert torch.all((ours - theirs).abs() <= tol), path.name
        torch.testing.assert_close(m.eval(q), m.eval_cos(q) / wo[:, 2:3])
        s = m.sample(Query(wi), u)
        ok = ref_wo[:, 2] > 0
        assert torch.equal(s.pdf > 0, ok), path.name
        assert (s.wo[ok] - ref_wo[ok]).abs().max() < 1e-3
        assert ((s.pdf[ok] - ref_spdf[ok]).abs() / ref_spdf[ok]).max() < 2e-3


@pytest.mark.mitsuba
def test_the_speed_suites_mitsuba_reference_evaluates_the_plugin_on_the_file(rgl_files, gen):
    """`MitsubaMeasured` (the speed suite's reference for the RGL reader) returns Mitsuba's BRDF x cos for the
    file it was given, at the queries given: equal to neumat's reader within the plugin test's tolerance; its rate
    is a positive number."""
    mitsuba_or_skip()
    from neumat.testing.drjit_parity import MitsubaMeasured, mitsuba_measured_evals_per_second

    n = 2000
    q = Query(_hemisphere(n, gen, dtype=torch.float32), _hemisphere(n, gen, dtype=torch.float32))
    for path in rgl_files[:2]:
        theirs = MitsubaMeasured(path)(q).double()
        ours = RglMaterial.from_file(path).eval_cos(q).double()
        assert theirs.shape == (n, 3) and theirs.abs().max() > 0
        assert torch.all((ours - theirs).abs() <= 1e-3 * (theirs.abs() + 1e-3 * theirs.abs().max())), path.name
    rate = mitsuba_measured_evals_per_second(rgl_files[0], q, repeats=1)
    assert math.isfinite(rate) and rate > 0


def test_rgl_sample_pdf_consistency(rgl_files, gen):
    """The pdf of sampled directions equals `pdf`, weights are eval * cos / pdf, and the pdf integrates
    over the hemisphere to the fraction of samples that stay above it (Monte Carlo, 4 sigma)."""
    m = RglMaterial.from_file(rgl_files[0])
    n = 4000
    wi = _hemisphere(1, gen, max_deg=60).expand(n, 3).contiguous()
    s = m.sample(Query(wi), torch.rand(n, 2, generator=gen, dtype=torch.float64))
    ok = s.pdf > 0
    q = Query(wi[ok], s.wo[ok])
    torch.testing.assert_close(m.pdf(q), s.pdf[ok], rtol=1e-5, atol=0)
    torch.testing.assert_close(s.weight[ok], m.eval(q) * s.wo[ok, 2:3] / s.pdf[ok, None])
    valid_frac = ok.double().mean().item()
    n_mc = 200000
    wi_mc = wi[:1].expand(n_mc, 3)
    wo_mc = _hemisphere(n_mc, gen)
    vals = m.pdf(Query(wi_mc, wo_mc)) * 2 * math.pi
    integral, err = vals.mean().item(), vals.std().item() / math.sqrt(n_mc)
    assert abs(integral - valid_frac) < 4 * (err + math.sqrt(valid_frac * (1 - valid_frac) / n) + 1e-3)


def test_rgl_dtype_device_and_horizon(rgl_files, gen):
    m = RglMaterial.from_file(rgl_files[0])
    wi, wo = _hemisphere(50, gen, dtype=torch.float32), _hemisphere(50, gen, dtype=torch.float32)
    f = m.eval(Query(wi, wo))
    assert f.dtype == torch.float32 and f.shape == (50, 3) and torch.isfinite(f).all()
    below = wo * torch.tensor([1.0, 1, -1])
    assert torch.all(m.eval(Query(wi, below)) == 0) and torch.all(m.pdf(Query(wi, below)) == 0)
    with pytest.raises(InputError, match="RglMaterial needs Query.wo"):
        m.pdf(Query(wi))


def _synthetic_rgl(path, seed: int = 0):
    """A small random RGL file (isotropic, 3 incident elevations) written with `write_tensor_file`. Like
    measured data, its VNDF vanishes as u_theta^3 at the pole, so the solid-angle pdf stays bounded, and
    falls off towards grazing half vectors."""
    from neumat.io.rgl import write_tensor_file
    rng = np.random.default_rng(seed)
    u_theta = np.linspace(0, 1, 32, dtype=np.float32)
    write_tensor_file(path, {
        "description": "synthetic", "phi_i": np.zeros(1, np.float32),
        "theta_i": np.array([0, 0.7, np.pi / 2], np.float32),
        "ndf": rng.random((2, 16), dtype=np.float32) + 0.1, "sigma": rng.random((2, 16), dtype=np.float32) + 0.5,
        "vndf": (rng.random((1, 3, 32, 32), dtype=np.float32) + 0.5) * u_theta ** 3 * (1 - u_theta) ** 2,
        "luminance": rng.random((1, 3, 8, 8), dtype=np.float32) + 0.1,
        "rgb": rng.random((1, 3, 3, 8, 8), dtype=np.float32), "jacobian": np.ones(1, np.uint8)})
    return path


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_cuda_matches_cpu(tmp_path, merl_table, gen):
    """Every evaluation runs on the query's device and agrees with the CPU result."""
    wi, wo = _hemisphere(4000, gen), _hemisphere(4000, gen)
    u = torch.rand(4000, 2, generator=gen, dtype=torch.float64)
    q, qc = Query(wi, wo), Query(wi.cuda(), wo.cuda())
    for m in (MerlMaterial(merl_table), MerlMaterial(merl_table, interpolate=True)):
        out = m.eval(qc)
        assert out.device.type == "cuda"
        torch.testing.assert_close(out.cpu(), m.eval(q), rtol=1e-10, atol=0)  # float64, FMA differences
    rgl = RglMaterial.from_file(_synthetic_rgl(tmp_path / "s.bsdf"))
    torch.testing.assert_close(rgl.eval(qc).cpu(), rgl.eval(q), rtol=1e-9, atol=1e-12)
    torch.testing.assert_close(rgl.pdf(qc).cpu(), rgl.pdf(q), rtol=1e-9, atol=1e-12)
    s, sc = rgl.sample(Query(wi), u), rgl.sample(Query(wi.cuda()), u.cuda())
    torch.testing.assert_close(sc.wo.cpu(), s.wo, rtol=1e-9, atol=1e-9)
    torch.testing.assert_close(sc.pdf.cpu(), s.pdf, rtol=1e-9, atol=1e-12)


def test_synthetic_rgl_sample_pdf_consistency(tmp_path, gen):
    """Sampling a synthetic file: sampled pdf equals `pdf`, and the pdf integrates to the valid fraction."""
    m = RglMaterial.from_file(_synthetic_rgl(tmp_path / "s.bsdf"))
    n = 4000
    wi = _hemisphere(1, gen, max_deg=50).expand(n, 3).contiguous()
    s = m.sample(Query(wi), torch.rand(n, 2, generator=gen, dtype=torch.float64))
    ok = s.pdf > 0
    torch.testing.assert_close(m.pdf(Query(wi[ok], s.wo[ok])), s.pdf[ok], rtol=1e-5, atol=0)
    n_mc = 200000
    vals = m.pdf(Query(wi[:1].expand(n_mc, 3), _hemisphere(n_mc, gen))) * 2 * math.pi
    frac = ok.double().mean().item()
    assert abs(vals.mean().item() - frac) < 4 * (vals.std().item() / math.sqrt(n_mc)
                                                 + math.sqrt(frac * (1 - frac) / n) + 1e-3)


@pytest.mark.mitsuba
@pytest.mark.parametrize("phi_range,reduction", [((-math.pi, math.pi), 1), ((-math.pi, 0), 2),
                                                  ((-math.pi, -math.pi / 2), 4)])
def test_anisotropic_rgl_matches_mitsuba(tmp_path, gen, phi_range, reduction):
    """Synthetic anisotropic files (4 incident azimuths over 2 pi, pi or pi / 2: Mitsuba's symmetry
    reductions 1, 2, 4) against the plugin, same tolerances as for the real files."""
    from neumat.io.rgl import write_tensor_file
    mi = mitsuba_or_skip()
    rng = np.random.default_rng(reduction)
    n_phi = 4
    write_tensor_file(tmp_path / "a.bsdf", {
        "description": "anisotropic", "phi_i": np.linspace(*phi_range, n_phi).astype(np.float32),
        "theta_i": np.array([0, 0.5, 1.0, np.pi / 2], np.float32),
        "ndf": rng.random((8, 16), dtype=np.float32) + 0.1, "sigma": rng.random((8, 16), dtype=np.float32) + 0.5,
        "vndf": rng.random((n_phi, 4, 16, 16), dtype=np.float32) + 0.1,
        "luminance": rng.random((n_phi, 4, 8, 8), dtype=np.float32) + 0.1,
        "rgb": rng.random((n_phi, 4, 3, 8, 8), dtype=np.float32), "jacobian": np.ones(1, np.uint8)})
    m = RglMaterial.from_file(tmp_path / "a.bsdf")
    assert not m.isotropic and m.reduction == reduction
    n = 3000
    wi, wo = _hemisphere(n, gen), _hemisphere(n, gen)
    bsdf = mi.load_dict({"type": "measured", "filename": str(tmp_path / "a.bsdf")})
    si = mi.SurfaceInteraction3f()
    si.wi = mi.Vector3f(wi.T.float().numpy())
    ctx, mwo = mi.BSDFContext(), mi.Vector3f(wo.T.float().numpy())
    ref = torch.from_numpy(np.array(bsdf.eval(ctx, si, mwo)).T).double()
    ref_pdf = torch.from_numpy(np.array(bsdf.pdf(ctx, si, mwo))).double()
    q = Query(wi, wo)
    for ours, theirs in ((m.eval_cos(q), ref), (m.pdf(q), ref_pdf)):
        assert torch.all((ours - theirs).abs() <= 1e-3 * (theirs.abs() + 1e-3 * theirs.abs().max()))
    u = torch.rand(n, 2, generator=gen, dtype=torch.float64)
    bs, _ = bsdf.sample(ctx, si, mi.Float(np.zeros(n, np.float32)), mi.Point2f(u.T.float().numpy()))
    ref_wo = torch.from_numpy(np.array(bs.wo).T).double()
    s = m.sample(Query(wi), u)
    ok = ref_wo[:, 2] > 0
    assert torch.equal(s.pdf > 0, ok)
    assert (s.wo[ok] - ref_wo[ok]).abs().max() < 1e-3


def _chi2_sample_vs_pdf(m: RglMaterial, wi: torch.Tensor, gen: torch.Generator, n: int = 60000,
                        n_cos: int = 12, n_phi: int = 24, sub: int = 8) -> float:
    """p-value of a chi-square test of `sample` against `pdf` for one wi: histogram over equal-solid-angle
    bins (cos theta x phi) plus one bin for failed samples; expected counts integrate `pdf` per bin with a
    sub x sub midpoint rule; cells expecting fewer than 5 samples are pooled."""
    s = m.sample(Query(wi.expand(n, 3).contiguous()), torch.rand(n, 2, generator=gen, dtype=torch.float64))
    ok = s.pdf > 0
    ct, ph = s.wo[ok, 2], torch.atan2(s.wo[ok, 1], s.wo[ok, 0]) % (2 * math.pi)
    i = (ct * n_cos).long().clamp(max=n_cos - 1) * n_phi + (ph / (2 * math.pi) * n_phi).long().clamp(max=n_phi - 1)
    observed = torch.bincount(i, minlength=n_cos * n_phi).double()
    c = (torch.arange(n_cos * sub, dtype=torch.float64) + 0.5) / (n_cos * sub)
    p = (torch.arange(n_phi * sub, dtype=torch.float64) + 0.5) / (n_phi * sub) * 2 * math.pi
    cc, pp = torch.meshgrid(c, p, indexing="ij")
    st = (1 - cc * cc).sqrt()
    wo = torch.stack([st * pp.cos(), st * pp.sin(), cc], -1).reshape(-1, 3)
    dens = m.pdf(Query(wi.expand(wo.shape[0], 3).contiguous(), wo)).reshape(n_cos, sub, n_phi, sub)
    expected = (dens.mean((1, 3)) * 2 * math.pi / (n_cos * n_phi)).reshape(-1) * n
    observed = torch.cat([observed, (~ok).sum().double()[None]])
    expected = torch.cat([expected, (n - expected.sum()).clamp(min=0)[None]])
    low = expected < 5
    obs = torch.cat([observed[~low], observed[low].sum()[None]]).numpy()
    exp = torch.cat([expected[~low], expected[low].sum()[None]]).numpy()
    keep = exp > 0
    chi2 = ((obs[keep] - exp[keep]) ** 2 / exp[keep]).sum()
    return float(stats.chi2.sf(chi2, keep.sum() - 1))


def test_rgl_sampling_chi2(rgl_files, tmp_path, gen):
    """Chi-square (Sidak-corrected over 4 tests, alpha 0.01) of samples against the pdf: paper_white and a
    synthetic file, at two incident directions each."""
    paper = [p for p in rgl_files if p.name.startswith("paper_white")] or rgl_files[:1]
    mats = [RglMaterial.from_file(paper[0]), RglMaterial.from_file(_synthetic_rgl(tmp_path / "s.bsdf"))]
    alpha = 1 - (1 - 0.01) ** (1 / 4)
    for m in mats:
        for theta in (0.3, 1.1):
            wi = torch.tensor([[math.sin(theta) * 0.6, math.sin(theta) * 0.8, math.cos(theta)]], dtype=torch.float64)
            assert _chi2_sample_vs_pdf(m, wi, gen) > alpha, (m.name, theta)


@pytest.mark.mitsuba
@pytest.mark.parametrize("reduction", [0, 1, 2, 4])
def test_rgl_float32_kernel_matches_mitsuba(rgl_files, tmp_path, gen, reduction):
    """The fused C evaluation (float32, autograd off: `neumat.nn.cpu_kernels.rgl_eval`) against Mitsuba 3
    `measured` with the float64 test's tolerance: every shared file (reduction 0) and synthetic anisotropic files
    (Mitsuba's symmetry reductions 1, 2, 4; measured worst 9.4e-5 of the tolerance's scale on both)."""
    from neumat.io.rgl import write_tensor_file
    from neumat.nn import cpu_kernels
    mi = mitsuba_or_skip()
    if cpu_kernels.library() is None:
        pytest.skip(f"no fused CPU kernels: {cpu_kernels.unavailable()}")
    paths = rgl_files
    if reduction:
        rng, n_phi = np.random.default_rng(reduction), 4
        phi_range = {1: (-math.pi, math.pi), 2: (-math.pi, 0), 4: (-math.pi, -math.pi / 2)}[reduction]
        write_tensor_file(tmp_path / "a.bsdf", {
            "description": "anisotropic", "phi_i": np.linspace(*phi_range, n_phi).astype(np.float32),
            "theta_i": np.array([0, 0.5, 1.0, np.pi / 2], np.float32),
            "ndf": rng.random((8, 16), dtype=np.float32) + 0.1, "sigma": rng.random((8, 16), dtype=np.float32) + 0.5,
            "vndf": rng.random((n_phi, 4, 16, 16), dtype=np.float32) + 0.1,
            "luminance": rng.random((n_phi, 4, 8, 8), dtype=np.float32) + 0.1,
            "rgb": rng.random((n_phi, 4, 3, 8, 8), dtype=np.float32), "jacobian": np.ones(1, np.uint8)})
        paths = [tmp_path / "a.bsdf"]
    n = 3000
    for path in paths:
        wi, wo = _hemisphere(n, gen).float(), _hemisphere(n, gen).float()
        wi[:30, 2] *= -1
        bsdf = mi.load_dict({"type": "measured", "filename": str(path)})
        si = mi.SurfaceInteraction3f()
        si.wi = mi.Vector3f(wi.T.numpy())
        ref = torch.from_numpy(np.array(bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(wo.T.numpy()))).T).double()
        m = RglMaterial.from_file(path)
        assert m.reduction == reduction
        with torch.no_grad():
            got = m.eval(Query(wi, wo))
        assert cpu_kernels.usable(wi, wo)
        tol = 1e-3 * (ref.abs() + 1e-3 * ref.abs().max())
        assert torch.all((got.double() * wo[:, 2:3].double() - ref).abs() <= tol), path.name
        assert (got[:30] == 0).all()
        with torch.no_grad():  # the kernel's tables are kept outside the material: it still pickles
            torch.testing.assert_close(pickle.loads(pickle.dumps(m)).eval(Query(wi, wo)), got)
