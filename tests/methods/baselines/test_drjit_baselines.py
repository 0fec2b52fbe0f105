"""Parity of the homogeneous baselines' Dr.Jit runtime (`neumat.export.drjit`: NBRDF and the naive MLP as the
"direction-mlp" program, the fitted GGX as "ggx") with their torch models on random queries, fp32 compute: values
within 1e-4 relative (NBRDF's max(exp(x) - 1, 0) also within 1e-6 absolute: where exp(x) is near 1 the subtraction
leaves the float32 rounding of exp, 6e-8, both in torch and Dr.Jit); GGX's pdf within 1e-4 relative, its sampler's
directions within 1e-4 and their pdfs within 1e-3 relative (sin / cos differ by an ulp; the lobe is sharp)."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from neumat.core.errors import InputError
from neumat.core.query import Query
from neumat.methods.baselines.ggx import GGXFit
from neumat.methods.baselines.naive_mlp import NaiveMLP
from neumat.methods.baselines.nbrdf import NBRDF

pytestmark = pytest.mark.mitsuba  # Dr.Jit's LLVM backend needs the LLVM that neumat.core.llvm finds


@pytest.fixture(scope="module")
def drjit_llvm():
    from mitsuba_util import mitsuba_or_skip
    mitsuba_or_skip()  # chooses an LLVM >= 16 before Dr.Jit loads one, or skips with the reason
    import drjit as dr
    return dr


def _dirs(n: int, g: torch.Generator) -> torch.Tensor:
    w = torch.nn.functional.normalize(torch.randn(n, 3, generator=g), dim=-1)
    w[:, 2] = w[:, 2].abs()
    return w


def _a3(w: torch.Tensor):
    from drjit.llvm.ad import Array3f, Float
    return Array3f(*(Float(c.contiguous().numpy()) for c in w.T))


def _t(x) -> torch.Tensor:
    a = np.array(x, dtype=np.float64)
    return torch.from_numpy(a.T.copy() if a.ndim == 2 else a)


def _runtime(model):
    from neumat.export.drjit.format import export_drjit
    from neumat.export.drjit.runtime import load_runtime
    return load_runtime(export_drjit(model.train(False)).source(), "llvm")


def _mlp_model(cls, bias: float, seed: int = 0, **config):
    torch.manual_seed(seed)
    model = cls(**config)
    with torch.no_grad():
        for lin in model.mlp.linears():
            lin.weight.normal_(0, 0.3)
        model.mlp.linears()[-1].bias.fill_(bias)  # values on a BRDF's scale
    return model


def _rel(got: torch.Tensor, ref: torch.Tensor, atol: float = 0.0) -> float:
    return float(((got - ref).abs() - atol).clamp(min=0).div(ref.abs().clamp(min=1e-30)).max())


@pytest.mark.parametrize("cls, config, bias, atol", [
    (NBRDF, {}, 0.3, 1e-6), (NBRDF, {"half": "theta", "fold_phi_d": True}, 0.3, 1e-6),
    (NBRDF, {"output": "exp", "activation": "tanh"}, -1.0, 0.0), (NaiveMLP, {}, -1.0, 0.0),
    (NaiveMLP, {"activation": "leaky_relu", "hidden_layers": 1}, -1.0, 0.0)],
    ids=["nbrdf", "nbrdf theta fold", "nbrdf exp tanh", "naive-mlp", "naive-mlp leaky"])
def test_direction_mlp_matches_torch(drjit_llvm, cls, config, bias, atol):
    model = _mlp_model(cls, bias, **config)
    g = torch.Generator().manual_seed(1)
    wi, wo = _dirs(20000, g), _dirs(20000, g)
    wo[:50, 2] *= -1  # below the horizon: 0
    got = _t(_runtime(model).eval(_a3(wi), _a3(wo)))
    with torch.no_grad():
        ref = model.eval(Query(wi, wo)).double()
    assert bool((ref[:50] == 0).all()) and bool((got[:50] == 0).all())
    assert float((ref > 0).double().mean()) > 0.5  # mostly positive values: the relative bound is tested
    assert _rel(got, ref, atol) < 1e-4


@pytest.mark.parametrize("config", [{"init_alpha": 0.2}, {"anisotropic": True}], ids=["isotropic", "anisotropic"])
def test_ggx_eval_pdf_and_sampler_match_torch(drjit_llvm, config):
    from drjit.llvm.ad import Float
    model = GGXFit(**config)
    with torch.no_grad():
        model.raw_diffuse.copy_(torch.tensor([0.1, -0.5, 0.3]))
        if config.get("anisotropic"):
            model.raw_alpha.copy_(torch.tensor([-1.0, 0.5]))
    rt = _runtime(model)
    assert rt.can_sample
    g = torch.Generator().manual_seed(2)
    wi, wo = _dirs(20000, g), _dirs(20000, g)
    with torch.no_grad():
        assert _rel(_t(rt.eval(_a3(wi), _a3(wo))), model.eval(Query(wi, wo)).double()) < 1e-4
        assert _rel(_t(rt.pdf(_a3(wi), _a3(wo))), model.pdf(Query(wi, wo)).double()) < 1e-4
        u = torch.rand(20000, 2, generator=g)
        ref = model.sample(Query(wi), u)
    wo_s, pdf_s = rt.sample(_a3(wi), Float(u[:, 0].numpy()), Float(u[:, 1].numpy()))
    assert float((_t(wo_s) - ref.wo.double()).abs().max()) < 1e-4
    assert _rel(_t(pdf_s), ref.pdf.double()) < 1e-3


def test_unsupported_configurations_are_refused(drjit_llvm):
    from neumat.export.drjit.format import export_drjit
    with pytest.raises(InputError, match="activation 'gelu' has no Dr.Jit form"):
        export_drjit(NaiveMLP(activation="gelu"))
