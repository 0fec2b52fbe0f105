"""The Dr.Jit runtime program "neural-appearance" (`neumat.export.drjit.neural_appearance`): the learned sampler's
directions, densities and weights against `NeuralAppearance.sample` / `pdf` on the same random numbers, and its value
against `eval`, fp32 compute. Where the result is a deterministic function of the inputs (pdf at given directions,
the value) within 1e-4 relative; a sampled direction is deterministic too except where u_x lies within float
rounding of a lobe boundary (the defensive share or w_d: the two implementations may pick different lobes), or where
the proxy's density is near-singular (alpha at its 1e-3 floor): those lanes are left out and counted."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from neumat.core.query import Query
from neumat.methods.neural_appearance.model import NeuralAppearance

pytestmark = pytest.mark.mitsuba  # Dr.Jit's LLVM backend needs the LLVM that neumat.core.llvm finds
N = 8000


@pytest.fixture(scope="module")
def drjit_llvm():
    from mitsuba_util import mitsuba_or_skip
    mitsuba_or_skip()
    import drjit as dr
    return dr


def na_model(**config) -> NeuralAppearance:
    """A small neural-appearance model whose decoder, frames and sampler all vary with the latent and wi."""
    torch.manual_seed(0)
    model = NeuralAppearance(**{"spatial_size": 16, **config})
    with torch.no_grad():
        for layer in model.mlp.linears():
            layer.weight.normal_(0, 1.0 / layer.in_features ** 0.5)
        model.mlp.linears()[-1].bias.fill_(-1.0)
        model.frame.decode.weight.normal_(0, 0.3)
        for layer in model.sampler.mlp.linears():
            layer.weight.normal_(0, 1.5 / layer.in_features ** 0.5)
    return model.train(False)


def _dirs(n, g):
    w = torch.nn.functional.normalize(torch.randn(n, 3, generator=g), dim=-1)
    w[:, 2] = w[:, 2].abs() * torch.where(torch.rand(n, generator=g) < 0.05, -1.0, 1.0)
    return w


def _off_horizons(model, q: Query) -> torch.Tensor:
    """Queries with |local z| > 0.01 in each learned shading frame (test_drjit_neumip.py's `_keep`)."""
    keep = torch.ones(len(q.wi), dtype=torch.bool)
    with torch.no_grad():
        z = model.spatial_latent(q)
        for k in range(model.frame.frames):
            t, b, n = model.frame.frame(z, k)
            keep &= ((q.wi * n).sum(-1).abs() > 0.01) & ((q.wo * n).sum(-1).abs() > 0.01)
    return keep


def footprints(n: int, g: torch.Generator) -> torch.Tensor:
    """Covariances in uv^2 (tests/methods/latent_mlp/test_drjit_multiscale.py): major standard deviation
    2^U(-12, -2), elongation U(1, 30), any orientation."""
    ang = torch.rand(n, generator=g) * np.pi
    s1 = torch.exp2(torch.rand(n, generator=g) * -10 - 2)
    s2 = s1 / (1 + 29 * torch.rand(n, generator=g))
    rot = torch.stack([torch.stack([ang.cos(), -ang.sin()], -1), torch.stack([ang.sin(), ang.cos()], -1)], -2)
    cov = rot @ torch.diag_embed(torch.stack([s1 * s1, s2 * s2], -1)) @ rot.transpose(1, 2)
    return 0.5 * (cov + cov.transpose(1, 2))


def _f(x):
    from drjit.llvm.ad import Float
    return Float(x.contiguous().float().numpy())


def _np(x) -> torch.Tensor:
    return torch.from_numpy(np.array(x, dtype=np.float64).copy())


def runtime_of(model):
    from neumat.export.drjit.format import export_drjit
    from neumat.export.drjit.runtime import load_runtime
    exported = export_drjit(model)
    assert exported.manifest["program"] == "neural-appearance"
    return load_runtime(exported.source(), "llvm")


def _rel(a, b):
    return (a - b).abs() / b.abs().clamp(min=1e-30)


CASES = {"anisotropic": {}, "isotropic": {"sampler_lobes": "isotropic"},
         "roulette albedo": {"level_selection": "roulette", "albedo": True}}


@pytest.mark.parametrize("footprint", [False, True], ids=["finest level", "footprint"])
@pytest.mark.parametrize("case", list(CASES))
def test_sampler_matches_torch(drjit_llvm, case, footprint):
    from drjit.llvm.ad import Array3f
    model = na_model(**CASES[case])
    rt = runtime_of(model)
    assert rt.can_sample and rt.spatially_varying
    g = torch.Generator().manual_seed(2)
    wi, wo_any = _dirs(N, g), _dirs(N, g)
    uv = torch.rand(N, 2, generator=g) * 3 - 1
    u = torch.rand(N, 2, generator=g)
    fp = footprints(N, g) if footprint else None
    fpd = None if fp is None else tuple(_f(fp[:, i, j]) for i, j in ((0, 0), (0, 1), (1, 1)))
    a3 = lambda w: Array3f(*(_f(c) for c in w.T))  # noqa: E731
    where = dict(uv=(_f(uv[:, 0]), _f(uv[:, 1])), footprint=fpd)
    q = Query(wi, uv=uv, footprint=fp)
    ref = model.sample(q, u)
    wo, pdf, f = rt.sample_eval(a3(wi), _f(u[:, 0]), _f(u[:, 1]), True, **where)
    wo, pdf, f = _np(wo).T, _np(pdf), _np(f).T
    # lanes away from a lobe boundary (module docstring)
    with torch.no_grad():
        lobes = model.lobes(q)
    u1 = (u[:, 0] - 0.05) / 0.95
    away = ((u[:, 0] - 0.05).abs() > 1e-5) & ((u1 - lobes.w_d).abs() > 1e-5) & (lobes.alpha.amin(-1) > 2e-3)
    up = (wi[:, 2] > 0) & away
    assert float(up.float().mean()) > 0.85
    wo_err = float((wo[up] - ref.wo[up].double()).abs().max())
    assert wo_err < 1e-4
    ok = up & (ref.pdf > 0) & (ref.wo[:, 2] > 0)  # below the horizon the runtime's density is 0 (Mitsuba's rule)
    assert bool((pdf[wo[:, 2] <= 0] == 0).all())
    err = _rel(pdf[ok], ref.pdf[ok].double())
    pdf_err = (float(err.quantile(0.999)), float(err.max()))
    # the lobes come from a latent filtered in float: sharp lobes amplify its last bits (max seen 1.8e-4)
    assert float(err.quantile(0.999)) < 1e-4 and float(err.max()) < 1e-3, float(err.max())
    assert bool((pdf[wi[:, 2] <= 0] == 0).all())
    # the weight: within 1e-4 but where wo's last-ulp difference meets a learned frame's horizon (there the lift
    # z = sqrt(1 - x^2 - y^2) amplifies it, tests/methods/latent_mlp/test_drjit_neumip.py); the value at the
    # runtime's own wo is deterministic: within 1e-4 on every lane away from those horizons
    weight = f * wo[:, 2:3].clamp(min=0) / torch.where(pdf > 0, pdf, 1.0)[:, None]
    sig = ok & (ref.weight.abs().amax(-1) > 1e-6)
    err = _rel(weight[sig], ref.weight[sig].double()).amax(-1)
    weight_err = (float((err > 1e-4).float().mean()), float(err.max()))
    assert float((err > 1e-4).float().mean()) < 5e-3 and float(err.max()) < 2e-3, float(err.max())
    wo32 = wo.float()
    q_at = Query(wi, wo32 / wo32.norm(dim=-1, keepdim=True), uv=uv, footprint=fp)
    with torch.no_grad():
        at = model.eval(q_at).double()
    keep = ok & _off_horizons(model, q_at) & (at.abs().amax(-1) > 0)
    err = _rel(f[keep], at[keep])
    value_err = float(err.max())
    assert float(err.max()) < 1e-4
    # the density and the value at given directions (deterministic: every lane with both above the horizon)
    pdf2 = _np(rt.pdf(a3(wi), a3(wo_any), True, **where))
    val, pdf3 = rt.eval_pdf(a3(wi), a3(wo_any), True, **where)
    with torch.no_grad():
        q2 = Query(wi, wo_any, uv=uv, footprint=fp)
        ref_pdf, ref_val = model.pdf(q2).double(), model.eval(q2).double()
    both = (wi[:, 2] > 0) & (wo_any[:, 2] > 0) & (lobes.alpha.amin(-1) > 2e-3)
    both_value = both & _off_horizons(model, q2)
    err = _rel(pdf2[both], ref_pdf[both])
    print(f"\n{case} footprint={footprint}: wo {wo_err:.1e}; pdf at samples q99.9 {pdf_err[0]:.1e} max "
          f"{pdf_err[1]:.1e}; weight >1e-4 in {weight_err[0]:.2%} max {weight_err[1]:.1e}; value at own wo "
          f"{value_err:.1e}; pdf at given wo q99.9 {float(err.quantile(0.999)):.1e} max {float(err.max()):.1e}",
          end=" ")
    assert float(err.max()) < 1e-4
    assert torch.equal(pdf2, _np(pdf3))
    assert float(_rel(_np(val).T[both_value], ref_val[both_value]).max()) < 1e-4
    assert bool((pdf2[~((wi[:, 2] > 0) & (wo_any[:, 2] > 0))] == 0).all())


def test_sample_alone_matches_sample_eval(drjit_llvm):
    from drjit.llvm.ad import Array3f
    rt = runtime_of(na_model())
    g = torch.Generator().manual_seed(5)
    wi, uv, u = _dirs(500, g), torch.rand(500, 2, generator=g), torch.rand(500, 2, generator=g)
    a = rt.sample(Array3f(*(_f(c) for c in wi.T)), _f(u[:, 0]), _f(u[:, 1]), True, (_f(uv[:, 0]), _f(uv[:, 1])))
    b = rt.sample_eval(Array3f(*(_f(c) for c in wi.T)), _f(u[:, 0]), _f(u[:, 1]), True, (_f(uv[:, 0]), _f(uv[:, 1])))
    assert torch.equal(_np(a[0]), _np(b[0])) and torch.equal(_np(a[1]), _np(b[1]))
