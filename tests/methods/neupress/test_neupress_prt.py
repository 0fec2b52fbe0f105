"""SH PRT from a full-sphere material (NeuPreSS Sec. 4.3): exactness for band-limited transport and lighting,
bilinear view interpolation (wrap in phi, clamp in theta, 0 below the horizon), lighting coefficients of
constant / tabulated / directional lights, convergence in the degree for a narrow lobe, files and checks."""
import math
from dataclasses import replace

import numpy as np
import pytest
import torch

from neumat import DataFormatError, InputError
from neumat.core.frames import frame_from_normal, to_local, to_world
from neumat.core.query import Query
from neumat.methods.neupress.model import NeuPreSS
from neumat.methods.neupress.prt import PRTConfig, SHPRT, sh_light_coefficients, sphere_quadrature
from neumat.nn.spherical_harmonics import real_sh, sh_count
from neumat.render.envmaps import equirect_to_dir
from neumat.render.lights import ConstantEnvironment, DirectionalLight, EnvironmentMap

SQRT_4PI = math.sqrt(4 * math.pi)


def _unit(v):
    v = torch.as_tensor(v, dtype=torch.float32)
    return v / v.norm(dim=-1, keepdim=True)


def _vertices(n, seed=0):
    g = torch.Generator().manual_seed(seed)
    return torch.rand(n, 3, generator=g) * 2 - 1, _unit(torch.randn(n, 3, generator=g))


def _bin_centres(normals, view_theta, view_phi):
    """World centre directions (V, T, P, 3) of the view bins, computed independently of the module."""
    cos_t = 1 - (torch.arange(view_theta, dtype=torch.float64) + 0.5) / view_theta
    phi = (torch.arange(view_phi, dtype=torch.float64) + 0.5) * 2 * math.pi / view_phi
    ct, ph = torch.meshgrid(cos_t, phi, indexing="ij")
    st = (1 - ct ** 2).sqrt()
    local = torch.stack([st * ph.cos(), st * ph.sin(), ct], -1).reshape(-1, 3).float()
    v, b = normals.shape[0], local.shape[0]
    t, bt = frame_from_normal(normals)
    rep = lambda a: a.repeat_interleave(b, 0)  # noqa: E731
    return to_world(local.repeat(v, 1), rep(t), rep(bt), rep(normals)).reshape(v, view_theta, view_phi, 3)


def _bin_coords(normals, wo, view_theta, view_phi):
    """Continuous view-bin coordinates (s, r) of wo, and cos theta, in the normals' frames."""
    t, b = frame_from_normal(normals)
    loc = to_local(wo, t, b, normals).double()
    s = (1 - loc[:, 2]) * view_theta - 0.5
    r = torch.remainder(torch.atan2(loc[:, 1], loc[:, 0]), 2 * math.pi) * view_phi / (2 * math.pi) - 0.5
    return s, r, loc[:, 2]


class PolyTransport:
    """S_hat(wi; x, wo) = sum_lm c_lm(x, wo) Y_lm(wi): band-limited in wi with known coefficients c, smooth
    (affine) in x and wo."""

    full_sphere = True

    def __init__(self, degree=2, seed=1):
        g = torch.Generator().manual_seed(seed)
        c = sh_count(degree)
        self.degree = degree
        self.A = torch.randn(c, 3, generator=g, dtype=torch.float64)
        self.Bx = 0.5 * torch.randn(3, c, 3, generator=g, dtype=torch.float64)
        self.Bo = 0.5 * torch.randn(3, c, 3, generator=g, dtype=torch.float64)

    def coeffs(self, x, wo):
        x, wo = x.double(), wo.double()
        return self.A + torch.einsum("ni,ick->nck", x, self.Bx) + torch.einsum("ni,ick->nck", wo, self.Bo)

    def eval(self, q):
        y = real_sh(q.wi.double(), self.degree)
        return (y[:, :, None] * self.coeffs(q.x, q.wo)).sum(1).to(q.dtype)


class ViewRamp:
    """S_hat constant in wi, equal to g(wo) = 1 + 0.3 s + 0.1 r (s, r: view-bin coordinates of wo around the
    vertex normal n, looked up by position x), so a_00 = sqrt(4 pi) g at bin centres and the rest is 0."""

    full_sphere = True

    def __init__(self, points, normals, view_theta, view_phi):
        self.points, self.normals, self.shape = points, normals, (view_theta, view_phi)

    def eval(self, q):
        idx = torch.cdist(q.x.float(), self.points).argmin(1)
        s, r, _ = _bin_coords(self.normals[idx], q.wo.float(), *self.shape)
        return (1 + 0.3 * s + 0.1 * r)[:, None].expand(-1, 3).to(q.dtype)


class Lobe:
    """A narrow lobe in wi around a direction that turns with wo: not band-limited."""

    full_sphere = True

    def __init__(self, kappa=20.0):
        self.kappa = kappa

    def eval(self, q):
        axis = _unit(q.wo.double() + torch.tensor([0.3, -0.2, 1.0], dtype=torch.float64)).double()
        val = torch.exp(self.kappa * ((q.wi.double() * axis).sum(-1) - 1))
        return (val[:, None] * torch.tensor([1.0, 0.7, 0.4], dtype=torch.float64)).to(q.dtype)


# ---- 1. exactness for band-limited transport ------------------------------------------------------------------
@pytest.mark.parametrize("rule, samples, tol", [("gauss", 256, 1e-4), ("fibonacci", 4096, 2e-4)])
def test_band_limited_transport_and_lighting_are_exact(rule, samples, tol):
    points, normals = _vertices(3)
    cfg = PRTConfig(degree=2, view_theta=3, view_phi=5, light_samples=samples, light_rule=rule, batch_size=3000)
    mat = PolyTransport()
    prt = SHPRT.from_material(mat, points, normals, cfg)
    assert prt.coefficients.shape == (3, 3, 5, 9, 3) and prt.coefficients.dtype == torch.float32

    wo = _bin_centres(normals, 3, 5)  # (V, T, P, 3)
    known = mat.coeffs(points[:, None, None].expand(-1, 3, 5, -1).reshape(-1, 3), wo.reshape(-1, 3))
    scale = known.abs().max()
    assert (prt.coefficients.reshape(-1, 9, 3).double() - known).abs().max() <= tol * scale

    e = torch.randn(9, 3, generator=torch.Generator().manual_seed(5), dtype=torch.float64)
    b = prt.light_coefficients(lambda d: real_sh(d, 2) @ e, samples=samples, rule=rule)
    assert b.shape == (9, 3)
    torch.testing.assert_close(b.double(), e, atol=tol * e.abs().max(), rtol=0)

    vi = torch.arange(3).repeat_interleave(15)
    out = prt.radiance(vi, wo.reshape(-1, 3), b)
    exact = (known * e).sum(1)  # Eq. 11 with the known coefficients
    assert (out.double() - exact).abs().max() <= 2 * tol * exact.abs().max()


def test_neupress_model_runs_through_the_precomputation():
    torch.manual_seed(0)
    model = NeuPreSS(features=16, width=16, layers=2, sampler_hidden=(8,))
    points, normals = _vertices(2)
    cfg = PRTConfig(view_theta=2, view_phi=4, light_samples=64, batch_size=500)
    prt = SHPRT.from_material(model, points, normals, cfg, progress=True)
    b = prt.light_coefficients(ConstantEnvironment([1.0, 1.0, 1.0]))
    # a constant unit environment gives the integral of S_hat over the sphere: compare with the quadrature
    wo = _bin_centres(normals, 2, 4)[0, 1, 2][None]
    d, w = sphere_quadrature(64)
    s = model.eval(Query(wi=d.float(), wo=wo.expand(len(d), 3), x=points[:1].expand(len(d), 3)))
    expected = (s.double() * w[:, None]).sum(0)
    torch.testing.assert_close(prt.radiance(torch.tensor([0]), wo, b)[0].double(), expected, rtol=1e-4, atol=1e-6)


# ---- 2. bilinear interpolation over the view bins ---------------------------------------------------------------
def test_view_interpolation_is_bilinear_wraps_in_phi_clamps_theta_and_cuts_at_the_horizon():
    T, P = 4, 6
    points = torch.tensor([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    normals = _unit([[0.0, 0.0, 1.0], [0.3, -0.5, 0.8]])
    cfg = PRTConfig(degree=1, view_theta=T, view_phi=P, light_samples=32)
    prt = SHPRT.from_material(ViewRamp(points, normals, T, P), points, normals, cfg)
    i, j = torch.meshgrid(torch.arange(T), torch.arange(P), indexing="ij")
    torch.testing.assert_close(prt.coefficients[:, :, :, 0, 0],
                               (SQRT_4PI * (1 + 0.3 * i + 0.1 * j)).float().expand(2, T, P), rtol=1e-5, atol=1e-5)
    assert prt.coefficients[:, :, :, 1:].abs().max() < 1e-5

    b = torch.zeros(4, 3)
    b[0] = 1.0 / SQRT_4PI  # radiance = a_00 / sqrt(4 pi) = g(wo) at bin centres
    g = torch.Generator().manual_seed(3)
    n = 4000
    vi = torch.randint(0, 2, (n,), generator=g)
    wo = _unit(torch.randn(n, 3, generator=g))
    out = prt.radiance(vi, wo, b).double()
    s, r, cos_t = _bin_coords(normals[vi], wo, T, P)
    sc = s.clamp(0, T - 1)
    wrap = r > P - 1  # between the centre of the last bin and phi = 2 pi
    wrap_lo = r < 0  # between phi = 0 and the centre of the first bin
    frac = torch.where(wrap, r - (P - 1), torch.where(wrap_lo, r + 1, torch.zeros_like(r)))
    expected = torch.where(wrap | wrap_lo, 1 + 0.3 * sc + 0.1 * (P - 1) * (1 - frac), 1 + 0.3 * sc + 0.1 * r)
    expected = torch.where(cos_t > 0, expected, torch.zeros_like(expected))
    assert wrap.any() and wrap_lo.any() and (s < 0).any() and (s > T - 1).any() and (cos_t <= 0).any()
    torch.testing.assert_close(out, expected[:, None].expand(-1, 3), rtol=1e-4, atol=1e-4)

    # triangles: the barycentric blend of the vertices' radiance
    tri = torch.stack([vi, 1 - vi, vi], -1)
    bary = torch.rand(n, 3, generator=g)
    bary = bary / bary.sum(-1, keepdim=True)
    blend = sum(bary[:, k:k + 1] * prt.radiance(tri[:, k], wo, b) for k in range(3))
    torch.testing.assert_close(prt.radiance_barycentric(tri, bary, wo, b), blend, rtol=1e-5, atol=1e-6)


# ---- 3. lighting coefficients ----------------------------------------------------------------------------------
def test_constant_environment_projects_to_the_dc_coefficient():
    c = torch.tensor([0.5, 1.0, 2.0])
    img = c.expand(6, 12, 3).numpy().copy()
    for env in (lambda d: c.double().expand(len(d), 3), ConstantEnvironment(c.tolist()), EnvironmentMap(img),
                EnvironmentMap(img, rotation=40.0)):
        b = sh_light_coefficients(env, 3)
        torch.testing.assert_close(b[0], c * SQRT_4PI, rtol=1e-5, atol=0)
        assert b[1:].abs().max() < 1e-5


def _random_map(h=8, w=16, seed=0):
    return np.random.default_rng(seed).random((h, w, 3)).astype(np.float32) * 3


@pytest.mark.parametrize("rotation", [0.0, 30.0])
def test_environment_map_coefficients_match_brute_force(rotation):
    env = EnvironmentMap(_random_map(), rotation=rotation, scale=1.5)
    # brute force: a fine midpoint grid in image coordinates (aligned with the texels of the rotated map,
    # u_world = u_map - rotation), sin theta weights, env.eval per direction
    hf, wf = 320, 640
    v, u = (torch.arange(hf, dtype=torch.float64) + 0.5) / hf, (torch.arange(wf, dtype=torch.float64) + 0.5) / wf
    vv, uu = torch.meshgrid(v, u, indexing="ij")
    d = equirect_to_dir(torch.stack([torch.remainder(uu.ravel() - rotation / 360, 1.0), vv.ravel()], -1))
    w = 2 * math.pi ** 2 * torch.sin(vv.ravel() * math.pi) / (hf * wf)
    ref = real_sh(d, 2).T @ (env.eval(d.float()).double() * w[:, None])
    scale = ref.abs().max()
    exact = sh_light_coefficients(env, 2).double()  # per-texel Gauss-Legendre (order chosen automatically)
    assert (exact - ref).abs().max() < 1e-4 * scale
    centres = sh_light_coefficients(env, 2, texel_nodes=1).double()  # texel centres, exact solid angles
    assert (centres[0] - ref[0]).abs().max() < 1e-4 * scale
    assert 1e-4 * scale < (centres - ref).abs().max() < 5e-2 * scale


def test_directional_light_coefficients():
    light = DirectionalLight([1.0, 2.0, -0.5], [1.0, 2.0, 3.0])
    b = sh_light_coefficients(light, 2)
    expected = real_sh(light.direction[None].double(), 2)[0, :, None] * torch.tensor([1.0, 2.0, 3.0]).double()
    torch.testing.assert_close(b.double(), expected, rtol=1e-6, atol=1e-7)


# ---- 4. high frequencies: the accuracy / efficiency trade-off --------------------------------------------------
def test_narrow_lobe_error_falls_with_the_degree():
    points, normals = _vertices(1, seed=2)
    normals = _unit([[0.1, 0.2, 1.0]])
    e = _unit([0.4, -0.3, 1.0]).double()

    def env(d):
        lum = 0.2 + torch.exp(6.0 * ((d.double() * e).sum(-1) - 1))
        return lum[:, None] * torch.tensor([1.0, 0.9, 0.8], dtype=torch.float64)

    wo = _bin_centres(normals, 2, 3).reshape(-1, 3)
    d, w = sphere_quadrature(20000)  # dense reference of Eq. 5 at the bin centres
    mat = Lobe()
    exact = torch.stack([(mat.eval(Query(wi=d, wo=o[None].double().expand(len(d), 3),
                                         x=points.double().expand(len(d), 3))) * env(d) * w[:, None]).sum(0)
                         for o in wo])
    errors = []
    for degree in (2, 4, 6):
        cfg = PRTConfig(degree=degree, view_theta=2, view_phi=3, light_samples=4096)
        prt = SHPRT.from_material(mat, points, normals, cfg)
        out = prt.radiance(torch.zeros(len(wo), dtype=torch.long), wo, prt.light_coefficients(env))
        errors.append(float(((out.double() - exact).abs().max() / exact.abs().max())))
    assert errors[0] > 0.05  # degree 2 (the paper's nine coefficients) is visibly off for a narrow lobe
    assert errors[0] > 2 * errors[1] > 4 * errors[2], errors


# ---- 5. files and checks ---------------------------------------------------------------------------------------
def test_save_load_round_trip_and_bad_files(tmp_path):
    points, normals = _vertices(2)
    cfg = PRTConfig(degree=1, view_theta=2, view_phi=3, light_samples=32)
    prt = SHPRT.from_material(PolyTransport(degree=3), points, normals, cfg)
    assert prt.size_bytes() == 2 * 2 * 3 * 4 * 3 * 2 and prt.size_bytes("fp32") == 2 * prt.size_bytes()
    back = SHPRT.load(prt.save(tmp_path / "a.prt"))
    assert back.config == prt.config
    torch.testing.assert_close(back.coefficients, prt.coefficients, rtol=0, atol=0)
    torch.testing.assert_close(back.normals, prt.normals, rtol=0, atol=0)
    wo, b = _unit(torch.randn(5, 3)), torch.randn(4, 3)
    vi = torch.tensor([0, 1, 1, 0, 1])
    torch.testing.assert_close(back.radiance(vi, wo, b), prt.radiance(vi, wo, b), rtol=0, atol=0)

    junk = tmp_path / "junk.prt"
    junk.write_bytes(b"not a safetensors file at all")
    with pytest.raises(DataFormatError):
        SHPRT.load(junk)
    from safetensors.torch import save_file
    save_file({"coefficients": torch.zeros(1)}, str(tmp_path / "other.prt"), metadata={"neumat": '{"type": "x"}'})
    with pytest.raises(DataFormatError, match="type"):
        SHPRT.load(tmp_path / "other.prt")
    save_file({"coefficients": torch.zeros(2, 2, 3, 5, 3), "points": points, "normals": normals},
              str(tmp_path / "bad.prt"),
              metadata={"neumat": '{"type": "sh-prt", "config": {"degree": 1, "view_theta": 2, "view_phi": 3}}'})
    with pytest.raises(DataFormatError, match="coefficients"):
        SHPRT.load(tmp_path / "bad.prt")
    with pytest.raises(InputError, match="does not exist"):
        SHPRT.load(tmp_path / "missing.prt")


def test_bad_inputs_raise_input_error():
    points, normals = _vertices(2)
    mat = PolyTransport()
    small = PRTConfig(view_theta=2, view_phi=2, light_samples=16)
    bad = [(dict(points=points[:, :2]), "points"), (dict(normals=normals * 2), "normals"),
           (dict(normals=normals[:1]), "normals"), (dict(config=PRTConfig(degree=-1)), "degree"),
           (dict(config=PRTConfig(view_theta=0)), "view_theta"), (dict(config=PRTConfig(view_phi=1.5)), "view_phi"),
           (dict(config=PRTConfig(light_samples=0)), "light_samples"),
           (dict(config=PRTConfig(light_rule="mc")), "light_rule"),
           (dict(config=PRTConfig(precision="fp16")), "precision"),
           (dict(material=object()), "material")]
    for kw, name in bad:
        args = dict(material=mat, points=points, normals=normals, config=small) | kw
        with pytest.raises(InputError, match=name):
            SHPRT.from_material(**args)

    class Hemisphere(PolyTransport):
        full_sphere = False

    with pytest.raises(InputError, match="full_sphere"):
        SHPRT.from_material(Hemisphere(), points, normals, small)

    prt = SHPRT.from_material(mat, points, normals, small)
    wo, b = _unit(torch.randn(3, 3)), torch.zeros(9, 3)
    for call, name in [(lambda: prt.radiance(torch.tensor([0.0, 1.0, 0.0]), wo, b), "vertex_index"),
                       (lambda: prt.radiance(torch.tensor([0, 2, 0]), wo, b), "vertex_index"),
                       (lambda: prt.radiance(torch.tensor([0, 1]), wo, b), "wo"),
                       (lambda: prt.radiance(torch.tensor([0, 1, 0]), wo * 3, b), "wo"),
                       (lambda: prt.radiance(torch.tensor([0, 1, 0]), wo, torch.zeros(4, 3)), "b"),
                       (lambda: prt.radiance_barycentric(torch.zeros(3, 2, dtype=torch.long), torch.ones(3, 2), wo, b),
                        "vertex_indices"),
                       (lambda: prt.radiance_barycentric(torch.zeros(3, 3, dtype=torch.long), torch.ones(2, 3), wo, b),
                        "bary"),
                       (lambda: prt.light_coefficients("sky"), "env"),
                       (lambda: prt.light_coefficients(lambda d: d[:, :2]), "env"),
                       (lambda: prt.light_coefficients(ConstantEnvironment(1.0), samples=0), "samples"),
                       (lambda: prt.size_bytes("fp8"), "precision")]:
        with pytest.raises(InputError, match=name):
            call()


# ---- 6. the batched precomputation ------------------------------------------------------------------------------
class _ThroughQueries:
    """A NeuPreSS model seen as a plain material: from_material evaluates it through eval(Query)."""

    full_sphere = True

    def __init__(self, model):
        self.model = model

    def eval(self, q):
        return self.model.eval(q)


@pytest.mark.parametrize("fourier", [dict(), dict(feature_mean=18.0, feature_std=1.0)])
def test_batched_precompute_matches_a_float64_brute_force_sum(fourier):
    """Both evaluation paths (NeuPreSS's separable features; any material's queries) against Eq. 10 summed per
    vertex and view in float64, with the paper's Fourier scale (angles up to ~100 rad) and ours."""
    torch.manual_seed(0)
    model = NeuPreSS(features=32, width=32, layers=3, sampler_hidden=(8,), **fourier)
    model.set_bounds(-torch.ones(3), torch.ones(3))
    points, normals = _vertices(3, seed=4)
    cfg = PRTConfig(view_theta=2, view_phi=3, light_samples=50, batch_size=200)  # chunks split vertices
    d, w = sphere_quadrature(50)
    basis_w = real_sh(d, 2) * w[:, None]
    wo = _bin_centres(normals, 2, 3).double()  # (V, T, P, 3)
    m64 = NeuPreSS(features=32, width=32, layers=3, sampler_hidden=(8,), **fourier).double()
    m64.load_state_dict(model.state_dict())
    expected = torch.stack([torch.stack([
        basis_w.T @ m64.eval(Query(wi=d, wo=o[None].expand(len(d), 3), x=points[v].double().expand(len(d), 3)))
        for o in wo[v].reshape(-1, 3)]) for v in range(3)]).reshape(3, 2, 3, 9, 3)
    scale = expected.abs().max()
    for material in (model, _ThroughQueries(model)):
        prt = SHPRT.from_material(material, points, normals, cfg)
        assert (prt.coefficients.double() - expected).abs().max() < 1e-4 * scale
    # bfloat16 (8-bit mantissa) network: within a few rounding units of the float64 sum even for angles of ~100
    # rad (they stay float32), and not the float32 path; refused where the features cannot be kept apart
    fast = SHPRT.from_material(model, points, normals, replace(cfg, precision="bf16"))
    error = (fast.coefficients.double() - expected).abs().max()
    assert 1e-5 * scale < error < 2e-2 * scale
    with pytest.raises(InputError, match="precision.*NeuPreSS"):
        SHPRT.from_material(_ThroughQueries(model), points, normals, replace(cfg, precision="bf16"))


def test_faces_are_kept_saved_and_checked(tmp_path):
    points, normals = _vertices(4)
    faces = torch.tensor([[0, 1, 2], [0, 2, 3]])
    cfg = PRTConfig(degree=1, view_theta=1, view_phi=2, light_samples=8)
    prt = SHPRT.from_material(PolyTransport(degree=1), points, normals, cfg, faces=faces)
    back = SHPRT.load(prt.save(tmp_path / "f.prt"))
    assert torch.equal(back.faces, faces) and torch.equal(back.to("cpu").faces, faces)
    assert SHPRT.load(SHPRT(prt.coefficients, points, normals, cfg).save(tmp_path / "n.prt")).faces is None
    for bad in (torch.tensor([[0, 1, 4]]), torch.tensor([[0.0, 1.0, 2.0]]), torch.tensor([0, 1, 2])):
        with pytest.raises(InputError, match="faces"):
            SHPRT(prt.coefficients, points, normals, cfg, faces=bad)
