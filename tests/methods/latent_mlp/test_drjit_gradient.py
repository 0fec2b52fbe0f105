"""Differentiating the latents through the Dr.Jit runtime (issue 50, item 3): `dr.enable_grad` on the runtime's
latent pyramid (`Pyramid.data`, every level's texels, (H, W, C) per level), a loss of the BRDF values, `dr.backward`;
the gradient against torch autograd of the same loss on the model's pyramid levels (spatial_precondition 0: the
levels are the parameters), at the finest level (bilinear) and over anisotropic footprints (the probe loop, a sum:
reverse-mode needs its `max_iterations=-1` hint), for neumip, neural-appearance (program "neural-appearance") and
multiscale ("latent-mlp"). Directly on the runtime and through Mitsuba's own BSDF.eval (the native plugin under
llvm_ad_rgb): within 1e-4 of the largest gradient entry, fp32. And through a tiny `prb` render (the plugin's
differentiable parameter "latent") against central differences."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from neumat.core.query import Query
from neumat.methods.latent_mlp.multiscale import MultiScale
from neumat.methods.latent_mlp.neumip import NeuMIP
from neumat.methods.neural_appearance.model import NeuralAppearance

pytestmark = pytest.mark.mitsuba
N = 3000


@pytest.fixture(scope="module")
def mi():
    from mitsuba_util import mitsuba_or_skip
    mitsuba_or_skip()
    from neumat.integrations import mitsuba_native
    return mitsuba_native.register()


def _model(cls):
    torch.manual_seed(0)
    model = cls(spatial_size=8, spatial_precondition=0.0)
    with torch.no_grad():
        for layer in model.mlp.linears():
            layer.weight.normal_(0, 1.5 / layer.in_features ** 0.5)
        if isinstance(model, MultiScale):
            model.mlp.linears()[-1].weight.mul_(0.3)
    return model.train(False)


def _queries(footprint: bool):
    g = torch.Generator().manual_seed(1)
    wi, wo = (torch.nn.functional.normalize(torch.randn(N, 3, generator=g), dim=-1) for _ in range(2))
    wi[:, 2], wo[:, 2] = wi[:, 2].abs() + 0.05, wo[:, 2].abs() + 0.05
    wi, wo = (torch.nn.functional.normalize(w, dim=-1) for w in (wi, wo))
    uv = torch.rand(N, 2, generator=g) * 2 - 0.5
    fp = None
    if footprint:  # standard deviations 2^-7 .. 2^-3 along x, elongation up to 8
        s = torch.exp2(torch.rand(N, generator=g) * -4 - 3)
        cov = torch.zeros(N, 2, 2)
        cov[:, 0, 0], cov[:, 1, 1] = s * s, (s / (1 + 7 * torch.rand(N, generator=g))) ** 2
        fp = cov
    return wi, wo, uv, fp, torch.rand(N, 3, generator=g)


def _torch_grad(model, wi, wo, uv, fp, cot, cosine: bool = False) -> np.ndarray:
    """d loss / d levels, flattened as the runtime's Pyramid.data ((H, W, C) per level, finest first)."""
    model.zero_grad()
    f = model.eval(Query(wi, wo, uv=uv, footprint=fp))
    if cosine:
        f = f * wo[:, 2:3]
    (f * cot).sum().backward()
    return np.concatenate([(torch.zeros_like(p) if p.grad is None else p.grad).permute(1, 2, 0).reshape(-1).numpy()
                           for p in model.spatial.raw])


def _close(ours: np.ndarray, ref: np.ndarray) -> float:
    return float(np.abs(ours - ref).max() / np.abs(ref).max())


@pytest.mark.parametrize("footprint", [False, True], ids=["finest level", "footprint"])
@pytest.mark.parametrize("cls", [NeuMIP, NeuralAppearance, MultiScale], ids=["neumip", "neural-appearance",
                                                                         "multiscale"])
def test_latent_gradient_matches_torch_autograd(mi, cls, footprint):
    import drjit as dr
    from drjit.llvm.ad import Array3f, Float
    from neumat.export.drjit.format import export_drjit
    from neumat.export.drjit.runtime import load_runtime
    model = _model(cls)
    wi, wo, uv, fp, cot = _queries(footprint)
    rt = load_runtime(export_drjit(model, "fp32").source(), "llvm")
    f = lambda x: Float(x.contiguous().float().numpy())  # noqa: E731
    data = rt.pyramid.data
    dr.enable_grad(data)
    fpd = None if fp is None else (f(fp[:, 0, 0]), f(fp[:, 0, 1]), f(fp[:, 1, 1]))
    out = rt.eval(Array3f(*(f(c) for c in wi.T)), Array3f(*(f(c) for c in wo.T)), True, (f(uv[:, 0]), f(uv[:, 1])),
                  fpd)
    dr.backward(dr.sum(out[0] * f(cot[:, 0]) + out[1] * f(cot[:, 1]) + out[2] * f(cot[:, 2])))
    ours = np.array(dr.grad(data), dtype=np.float64)
    ref = _torch_grad(model, wi, wo, uv, fp, cot).astype(np.float64)
    err = _close(ours, ref)
    print(f"relative gradient error {err:.2e}", end=" ")
    assert np.abs(ref).max() > 0 and err < 1e-4


def test_latent_gradient_through_mitsuba_bsdf_eval(mi, tmp_path):
    """The native plugin's BSDF.eval (f cos, radiance transport, si.uv) under llvm_ad_rgb, differentiated in
    Mitsuba's own types."""
    import drjit as dr
    from neumat.catalog.modelfile import save_model
    model = _model(NeuralAppearance)
    path = save_model(model.runtime(), tmp_path / "na.nmat")
    bsdf = mi.load_dict({"type": "neumat", "filename": str(path)})
    assert "NeumatNativeBSDF" in str(bsdf)
    wi, wo, uv, _, cot = _queries(False)
    f = lambda x: mi.Float(x.contiguous().float().numpy())  # noqa: E731
    si = dr.zeros(mi.SurfaceInteraction3f, N)
    si.wi = mi.Vector3f(*(f(c) for c in wi.T))
    si.uv = mi.Point2f(f(uv[:, 0]), f(uv[:, 1]))
    data = bsdf.runtime.pyramid.data
    dr.enable_grad(data)
    value = bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(*(f(c) for c in wo.T)))
    dr.backward(dr.sum(value[0] * f(cot[:, 0]) + value[1] * f(cot[:, 1]) + value[2] * f(cot[:, 2])))
    ours = np.array(dr.grad(data), dtype=np.float64)
    ref = _torch_grad(model, wi, wo, uv, None, cot, cosine=True).astype(np.float64)
    err = _close(ours, ref)
    print(f"relative gradient error {err:.2e}", end=" ")
    assert err < 1e-4


def test_latent_gradient_through_a_tiny_prb_render(mi, tmp_path):
    """A 16^2, 4 spp render with Mitsuba's `prb` integrator (direct light only: max_depth 2) of a neumip sphere;
    the latent is the native BSDF's differentiable parameter "latent" (`mi.traverse`). prb's adjoint pass replays
    the paths of `seed_grad`: its gradient of the mean pixel is the derivative of that render, which central
    differences along a random direction of the latents reproduce (1e-3 relative; FD step 1e-3). neumip samples
    cosine-weighted, independent of the latents; a model whose sampler reads them (neural-appearance) gets prb's
    gradient with the sampling held fixed, which differences of re-sampled renders do not reproduce."""
    import drjit as dr
    from neumat.catalog.modelfile import save_model
    model = _model(NeuMIP)
    path = save_model(model, tmp_path / "neumip.nmat")
    scene = mi.load_dict({
        "type": "scene", "integrator": {"type": "prb", "max_depth": 2},
        "sensor": {"type": "perspective", "fov": 30,
                   "to_world": mi.ScalarTransform4f().look_at(origin=[0, 1.5, 3.5], target=[0, 0, 0], up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": 16, "height": 16, "rfilter": {"type": "box"}},
                   "sampler": {"type": "independent", "sample_count": 4}},
        "sphere": {"type": "sphere", "bsdf": {"type": "neumat", "filename": str(path)}},
        "sun": {"type": "directional", "direction": [0.3, -1, -0.4], "irradiance": 3.0}})
    params = mi.traverse(scene)
    key = "sphere.bsdf.latent"
    assert key in params.keys()
    base = np.array(params[key]).copy()
    dr.enable_grad(params[key])
    params.update()
    dr.backward(dr.mean(mi.render(scene, params, spp=4, seed=3, seed_grad=5), axis=None))
    grad = np.array(dr.grad(params[key]), dtype=np.float64)
    d = np.random.default_rng(0).standard_normal(base.shape).astype(np.float32)
    eps, vals = 1e-3, []
    for sign in (1, -1):
        params[key] = mi.Float(base + sign * eps * d)
        params.update()
        vals.append(np.array(mi.render(scene, params, spp=4, seed=5), dtype=np.float64).mean())
    fd, ad = (vals[0] - vals[1]) / (2 * eps), float((grad * d).sum())
    print(f"fd {fd:.6e} ad {ad:.6e}", end=" ")
    assert abs(ad) > 0 and abs(ad - fd) < 1e-3 * abs(fd)
