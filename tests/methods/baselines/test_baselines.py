"""BRDF baselines (naive MLP, NBRDF, fitted GGX): registry and rebuild, configs, size and FLOP hand counts,
NBRDF's input and output against the authors' formulas, short fits to an analytic material, GGX parameter
recovery and a chi-square test of the GGX sampler."""
from __future__ import annotations

import math
from dataclasses import replace

import pytest
import torch

from neumat.core.errors import InputError
from neumat.core.material import Material
from neumat.core.query import Query
from neumat.fit.method import recipe_for
from neumat.fit.trainer import fit
from neumat.metrics.hdr import reflectance_errors
from neumat.methods.baselines.ggx import GGXFit
from neumat.methods.baselines.naive_mlp import NaiveMLP
from neumat.methods.baselines.nbrdf import NBRDF
from neumat.models.registry import model_class
from neumat.nn import cpu_kernels
from neumat.reflectance.analytic import Plastic
from neumat.reflectance.microfacet import fresnel_schlick, microfacet_brdf
from neumat.testing.chi2 import chi2_material
from neumat.warp.hemisphere import sample_cosine_hemisphere

BASELINES = {"naive-mlp": NaiveMLP, "nbrdf": NBRDF, "ggx": GGXFit}


def _queries(n: int, gen: torch.Generator, dtype=torch.float32) -> Query:
    wi = sample_cosine_hemisphere(torch.rand(n, 2, generator=gen, dtype=torch.float64))
    wo = sample_cosine_hemisphere(torch.rand(n, 2, generator=gen, dtype=torch.float64))
    return Query(wi.to(dtype), wo.to(dtype))


class DiffuseGGX(Material):
    """Closed-form diffuse + GGX (Schlick) reference: kd / pi + D G1 G1 F / (4 cos_i cos_o), the GGX baseline's
    own family, so that its parameters are known exactly."""

    def __init__(self, kd, f0, alpha_x: float, alpha_y: float) -> None:
        self.kd, self.f0, self.alpha_x, self.alpha_y = torch.tensor(kd), torch.tensor(f0), alpha_x, alpha_y

    def eval(self, q: Query) -> torch.Tensor:
        f0 = self.f0.to(q.dtype)
        spec = microfacet_brdf(q.wi, q.wo, self.alpha_x, self.alpha_y, lambda c: fresnel_schlick(c, f0))
        f = self.kd.to(q.dtype) / math.pi + spec
        up = (q.wi[:, 2] > 0) & (q.wo[:, 2] > 0)
        return torch.where(up.unsqueeze(-1), f, torch.zeros_like(f))


@pytest.mark.parametrize("name", sorted(BASELINES))
def test_registered_and_rebuildable(name, gen):
    cls = model_class(name)
    assert cls is BASELINES[name]
    torch.manual_seed(0)
    a = cls()
    with torch.no_grad():
        for p in a.parameters():
            p.add_(0.1 * torch.randn_like(p))
    b = cls(config=a.cfg)
    b.load_state_dict(a.state_dict())
    q = _queries(64, gen)
    assert a.name == name and a.eval(q).shape == (64, 3)
    assert torch.equal(a.eval(q), b.eval(q))
    below = Query(q.wi, q.wo * torch.tensor([1.0, 1.0, -1.0]))
    assert torch.all(a.eval(below) == 0)
    assert a.eval(q.to(dtype=torch.float64)).dtype == torch.float64


@pytest.mark.parametrize("name, bad", [
    ("naive-mlp", {"hidden": 0}), ("naive-mlp", {"activation": "swish"}), ("naive-mlp", {"depth": 3}),
    ("nbrdf", {"output": "softplus"}), ("nbrdf", {"hidden_layers": -1}), ("nbrdf", {"init_range": 0.0}),
    ("ggx", {"alpha_min": 0.0}), ("ggx", {"init_alpha": 2.0}), ("ggx", {"init_diffuse": 1.0}),
    ("ggx", {"anisotropic": 1}), ("ggx", {"min_lobe_probability": 0.7}),
])
def test_bad_config_raises(name, bad):
    with pytest.raises(InputError):
        model_class(name)(**bad)


def test_size_and_flops_hand_counts():
    # naive MLP 6-64-64-64-3: weights + biases; 2 in out per layer + one per hidden activation
    params = (6 * 64 + 64) + 2 * (64 * 64 + 64) + (64 * 3 + 3)
    assert params == 8963
    m = NaiveMLP()
    assert m.size_bytes("fp16") == 2 * params and m.size_bytes("fp32") == 4 * params
    assert m.flops() == 2 * (6 * 64 + 2 * 64 * 64 + 64 * 3) + 3 * 64 == 17728
    # NBRDF 6-21-21-3 (the paper: 675 weights, 1.35 kB at fp16)
    n = NBRDF()
    assert n.size_bytes("fp16") == 2 * 675 and n.size_bytes("fp32") == 4 * 675
    assert n.flops() == 2 * (6 * 21 + 21 * 21 + 21 * 3) + 2 * 21 == 1302
    # GGX: 3 diffuse + 3 specular + 1 (2) alpha floats; FLOPs by hand (see FLOPS_ISOTROPIC)
    assert GGXFit().size_bytes("fp16") == 14 and GGXFit(anisotropic=True).size_bytes("fp32") == 32
    assert GGXFit().flops() == 12 + 5 + 8 + 16 + 13 + 8 + 6 == 68
    assert GGXFit(anisotropic=True).flops() == 68 + 4 + 2 * 3
    with pytest.raises(InputError):
        m.size_bytes("fp8")


def test_nbrdf_input_and_output_follow_the_authors_code(gen):
    q = _queries(500, gen, torch.float64)
    x = NBRDF.encode(q.wi, q.wo)
    h, d = x[:, :3], x[:, 3:]
    ref_h = (q.wi + q.wo) / (q.wi + q.wo).norm(dim=-1, keepdim=True)
    torch.testing.assert_close(h, ref_h)
    torch.testing.assert_close(d.norm(dim=-1), torch.ones(500, dtype=torch.float64))
    torch.testing.assert_close(d[:, 2], (q.wi * ref_h).sum(-1))  # cos theta_d = wi . h
    # the authors' brdf_to_rgb recovers cos(theta_i) from (h, d): cos td cos th - sin td cos pd sin th
    th = torch.atan2(h[:, :2].norm(dim=-1), h[:, 2])
    td = torch.atan2(d[:, :2].norm(dim=-1), d[:, 2])
    pd = torch.atan2(d[:, 1], d[:, 0])
    torch.testing.assert_close(torch.cos(td) * torch.cos(th) - torch.sin(td) * torch.cos(pd) * torch.sin(th),
                               q.wi[:, 2])
    # output max(exp(x) - 1, 0): with the last layer's bias at +-1 and zero weights, e - 1 and 0
    m = NBRDF().double()
    last = m.mlp.linears()[-1]
    with torch.no_grad():
        last.weight.zero_()
        last.bias.copy_(torch.tensor([1.0, -1.0, 0.0]))
    f = m.eval(q)
    torch.testing.assert_close(f, torch.tensor([math.e - 1, 0.0, 0.0], dtype=torch.float64).expand(500, 3))
    for lin in m.mlp.linears():
        assert lin.weight.abs().max() <= 0.05


def test_recipes():
    r = recipe_for("nbrdf")  # the authors' code: 640k samples / 512 x 100 epochs, Adam 5e-4, eps 1e-15
    assert (r.steps, r.batch_size, r.lr, r.eps, r.loss, r.queries) == (
        125_000, 512, 5e-4, 1e-15, "log_cos", "rusinkiewicz")
    assert recipe_for("naive-mlp").loss == "log_cos"
    assert recipe_for("ggx").queries == "rusinkiewicz"


# Short CPU fits to a rough plastic (Lambert under a dielectric GGX coat): stated relative L1 errors
# (reflectance_errors rel_err over 2^15 cosine-weighted configurations). Measured: naive 0.115, NBRDF 0.063,
# GGX 0.079 (GGX + Lambert cannot represent the Fresnel-weighted plastic exactly).
@pytest.mark.parametrize("name, steps, batch, lr, max_rel", [
    ("naive-mlp", 300, 1024, 3e-3, 0.15),
    ("nbrdf", 400, 512, 1e-2, 0.09),
    ("ggx", 150, 2048, 5e-2, 0.09),
])
def test_fits_analytic_material(name, steps, batch, lr, max_rel):
    source = Plastic(diffuse=(0.6, 0.3, 0.15), roughness=0.3)
    torch.manual_seed(0)
    model = model_class(name)()
    before = reflectance_errors(model, source, n=2 ** 15)["rel_err"]
    recipe = replace(recipe_for(name), batch_size=batch, lr=lr, schedule="cosine", lr_min=lr / 20)
    fit(model, source, recipe, steps=steps, progress=False)
    err = reflectance_errors(model, source, n=2 ** 15)
    assert err["rel_err"] < max_rel < before, (err, before)


@pytest.mark.parametrize("anisotropic, alpha", [(False, (0.15, 0.15)), (True, (0.1, 0.4))])
def test_ggx_recovers_known_parameters(anisotropic, alpha):
    kd, f0 = (0.5, 0.3, 0.1), (0.9, 0.6, 0.3)
    source = DiffuseGGX(kd, f0, *alpha)
    model = GGXFit(anisotropic=anisotropic)
    fit(model, source, replace(recipe_for("ggx"), batch_size=2048, lr=5e-2), steps=200, progress=False)
    torch.testing.assert_close(model.diffuse.detach(), torch.tensor(kd), atol=3e-3, rtol=0)
    torch.testing.assert_close(model.specular.detach(), torch.tensor(f0), atol=3e-3, rtol=0)
    torch.testing.assert_close(model.alpha.detach(), torch.tensor(alpha), atol=0, rtol=1e-2)


@pytest.mark.parametrize("anisotropic", [False, True])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_ggx_eval_matches_the_microfacet_formula_in_and_across_chunks(anisotropic, dtype, gen):
    """GGXFit.eval (few-operation kernel, cached constants, chunks; float32 without autograd: the fused C kernel) =
    kd / pi + `microfacet_brdf` (Schlick), 0 below the horizon, within float rounding; with and without autograd,
    on one chunk and across several."""
    model = GGXFit(anisotropic=anisotropic).to(dtype)
    with torch.no_grad():
        model.raw_alpha.copy_(torch.tensor([-2.0, 0.5][: model.raw_alpha.numel()]))
        model.raw_specular.copy_(torch.tensor([0.5, -1.0, 2.0]))
    q = _queries(3000, gen, dtype)
    wi, wo = q.wi.clone(), q.wo.clone()
    wi[::7, 2] *= -1
    wo[::11] = torch.tensor([0.0, 0.0, -1.0], dtype=dtype)
    wo[::13] = torch.tensor([0.0, 0.0, 1.0], dtype=dtype)
    q = Query(wi, wo)
    def expected():
        a = model.alpha.detach()
        ref = DiffuseGGX((0.0,) * 3, (0.0,) * 3, a[0].item(), a[1].item())
        ref.kd, ref.f0 = model.diffuse.detach(), model.specular.detach()  # at the model's precision
        return ref.eval(q)

    tol = dict(rtol=4e-6, atol=0) if dtype == torch.float32 else dict(rtol=1e-13, atol=0)
    with torch.no_grad():
        before = cpu_kernels.calls[0]
        torch.testing.assert_close(model.eval(q), expected(), **tol)
        kernel = dtype == torch.float32 and cpu_kernels.library() is not None
        assert cpu_kernels.calls[0] == before + kernel  # float32 without autograd: the fused kernel (its own test)
        torch.testing.assert_close(model.eval(q, chunk=256), expected(), **tol)
        model.raw_diffuse.add_(0.5)  # an in-place parameter update invalidates the cached constants
        torch.testing.assert_close(model.eval(q, chunk=1000), expected(), **tol)
    f = model.eval(q, chunk=1000)
    assert f.requires_grad
    f.sum().backward()
    assert all(torch.isfinite(p.grad).all() for p in model.parameters())


@pytest.mark.parametrize("anisotropic, wi", [(False, (0.3, 0.2, 0.93)), (True, (0.7, -0.3, 0.4)),
                                             (False, (0.95, 0.0, 0.05))])
def test_ggx_sampling_chi2(anisotropic, wi):
    model = GGXFit(anisotropic=anisotropic).double()
    with torch.no_grad():
        model.raw_alpha.copy_(torch.tensor([-1.5, 0.3][: model.raw_alpha.numel()]))
        model.raw_diffuse.copy_(torch.tensor([-1.0, -1.5, -2.0]))
    wi = torch.tensor(wi, dtype=torch.float64)
    result = chi2_material(model, wi / wi.norm(), n_samples=200_000, res=(40, 40))
    assert result, result.message
    # weight = f cos / pdf on the sampled directions
    q = Query(wi.expand(1000, 3) / wi.norm())
    s = model.sample(q, torch.rand(1000, 2, generator=torch.Generator().manual_seed(3), dtype=torch.float64))
    ok = s.pdf > 0
    f = model.eval(Query(q.wi[ok], s.wo[ok]))
    torch.testing.assert_close(s.weight[ok], f * s.wo[ok, 2:3] / s.pdf[ok].unsqueeze(-1))
    below = model.sample(Query(torch.tensor([[0.0, 0.6, -0.8]], dtype=torch.float64)),
                         torch.full((1, 2), 0.5, dtype=torch.float64))
    assert below.pdf.item() == 0 and torch.all(below.weight == 0)


def test_ggx_starts_find_a_sharp_lobe_a_single_start_misses():
    """The GGX recipe's trial starts (alpha_starts): on a sharp GGX source (alpha 0.01) the fit from the default
    start alone stops short (measured: alpha 0.0131, F0 red 0.47, held-out log error 0.0040), the best of three
    starts recovers it (0.0100, 0.85, 0.00052); bad options are refused before any trial runs."""
    source = DiffuseGGX((0.02, 0.02, 0.02), (0.9, 0.6, 0.3), 0.01, 0.01)
    fits = {}
    for starts in ([], [0.3, 0.05, 0.01]):
        recipe = replace(recipe_for("ggx"), steps=300, batch_size=4096,
                         options={"alpha_starts": starts, "start_steps": 60})
        model = GGXFit()
        fit(model, source, recipe, progress=False)
        fits[len(starts)] = model, reflectance_errors(model, source, n=2 ** 14)["log_err"]
    (single, single_err), (best, best_err) = fits[0], fits[3]
    torch.testing.assert_close(best.alpha.detach(), torch.tensor([0.01, 0.01]), atol=0, rtol=0.03)
    assert float(single.alpha[0].detach()) > 0.012 and best_err < 0.25 * single_err, (single_err, best_err)
    for bad, why in (({"alpha_starts": [0.3, 2.0]}, r"^ggx recipe options: option.alpha_starts: expected alphas in "
                                                    r"\(0.001, 1.0\) \(the model's alpha_min, alpha_max\), "
                                                    r"got \[0.3, 2.0\]$"),
                     ({"alpha_starts": "0.3"}, r"^ggx recipe options: option.alpha_starts: expected a number, "
                                               r"got '0.3'$"),
                     ({"start_steps": 0}, r"^ggx recipe options: option.start_steps: expected a value >= 1, got 0$")):
        recipe = replace(recipe_for("ggx"), options={**recipe_for("ggx").options, **bad})
        with pytest.raises(InputError, match=why):
            fit(GGXFit(), source, recipe, steps=1, progress=False)
