"""The native Mitsuba BSDF (`neumat.integrations.mitsuba_native`): a NeuBRDF .nmat (or its drjit export) evaluated by
the Dr.Jit runtime inside Mitsuba's kernels. Against the torch bridge on the same file: eval / pdf / eval_pdf /
sample values, both transport modes; Mitsuba's chi2 test of its sampler; a render equal to the bridge's within
float error (the same cosine warp on the same random numbers); no torch import while loading and rendering a drjit
export; a cuda_ad_rgb run (skipped without a GPU)."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from mitsuba_util import bsdf_chi2_test, mi_vector, sphere_scene, to_torch
from neumat.catalog.modelfile import save_model
from neumat.methods.neubrdf.model import NeuBRDF

pytestmark = pytest.mark.mitsuba
SRC = str(Path(__file__).resolve().parents[2] / "src")


@pytest.fixture(scope="module")
def mi():
    from mitsuba_util import mitsuba_or_skip
    mitsuba_or_skip()
    from neumat.integrations import mitsuba as plugin
    return plugin.register()


@pytest.fixture(scope="module")
def nmat(tmp_path_factory) -> Path:
    """A small NeuBRDF in its shipped (runtime) form, values in a BRDF's range, not reciprocal."""
    torch.manual_seed(0)
    model = NeuBRDF(nside=8, feature_dim=8, index_bits=5, hidden=16, direction_inputs="hd_warp")
    with torch.no_grad():
        last = model.mlp.linears()[-1]
        last.weight.mul_(0.3)
        last.bias.copy_(torch.tensor([-1.0, -1.3, -1.6]))
    return save_model(model.train(False).runtime(), tmp_path_factory.mktemp("native") / "neubrdf.nmat")


def _dirs(n: int, g: torch.Generator, below: float = 0.1) -> torch.Tensor:
    v = torch.randn(n, 3, generator=g)
    v[:, 2] = v[:, 2].abs() * torch.where(torch.rand(n, generator=g) < below, -1.0, 1.0)
    return v / v.norm(dim=-1, keepdim=True)


def _si(mi, wi: torch.Tensor):
    import drjit as dr
    si = dr.zeros(mi.SurfaceInteraction3f, wi.shape[0])
    si.wi = mi_vector(mi, wi)
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    return si


def test_the_plugin_picks_the_native_path_for_a_neubrdf_file(mi, nmat):
    native = mi.load_dict({"type": "neumat", "filename": str(nmat)})
    bridge = mi.load_dict({"type": "neumat", "material": str(nmat), "native": False})
    assert "NeumatNativeBSDF" in str(native) and "NeumatBSDF[" in str(bridge)
    # a source without a Dr.Jit form goes through the bridge
    assert "NeumatBSDF[" in str(mi.load_dict({"type": "neumat", "material": "ggx:roughness=0.3"}))


def test_eval_pdf_and_sample_match_the_torch_bridge(mi, nmat):
    from neumat.integrations import mitsuba as plugin
    native = mi.load_dict({"type": "neumat", "filename": str(nmat)})
    bridge = mi.load_dict({"type": "neumat", "filename": str(nmat), "native": False})
    g = torch.Generator().manual_seed(3)
    n = 5000
    viewer, light = _dirs(n, g), _dirs(n, g)
    for mode in (mi.TransportMode.Radiance, mi.TransportMode.Importance):
        ctx = mi.BSDFContext(mode)
        with plugin.evaluated_mode():  # the bridge needs it; the native BSDF runs in either mode
            theirs = [to_torch(v) for v in bridge.eval_pdf(ctx, _si(mi, viewer), mi_vector(mi, light))]
        ours = [to_torch(v) for v in native.eval_pdf(ctx, _si(mi, viewer), mi_vector(mi, light))]
        up = (viewer[:, 2] > 0) & (light[:, 2] > 0)
        assert bool(up.any()) and bool((ours[0][~up] == 0).all()) and bool((ours[1][light[:, 2] <= 0] == 0).all())
        assert torch.allclose(ours[0], theirs[0], rtol=1e-4, atol=1e-7)
        assert torch.allclose(ours[1], theirs[1], rtol=1e-5, atol=1e-7)
        assert torch.allclose(to_torch(native.eval(ctx, _si(mi, viewer), mi_vector(mi, light))), ours[0])
        assert torch.allclose(to_torch(native.pdf(ctx, _si(mi, viewer), mi_vector(mi, light))), ours[1])
    # the model is not reciprocal: the two transport modes differ, so the swap above was tested
    ctx, imp = mi.BSDFContext(), mi.BSDFContext(mi.TransportMode.Importance)
    a = to_torch(native.eval(ctx, _si(mi, viewer), mi_vector(mi, light)))
    b = to_torch(native.eval(imp, _si(mi, viewer), mi_vector(mi, light))) * (viewer[:, 2:3] / light[:, 2:3]).double()
    assert not torch.allclose(a, b, rtol=1e-3)
    # sample: the bridge's cosine warp on the same numbers, pdf and weight = eval / pdf
    u = torch.rand(n, 2, generator=g)
    s2 = mi.Point2f(mi.Float(u[:, 0].contiguous()), mi.Float(u[:, 1].contiguous()))
    bs, weight = native.sample(ctx, _si(mi, viewer), mi.Float(0.5), s2)
    with plugin.evaluated_mode():
        bs_b, weight_b = bridge.sample(ctx, _si(mi, viewer), mi.Float(0.5), s2)
    front = viewer[:, 2] > 0  # a failed sample's wo is unused (the bridge leaves it at the normal)
    assert torch.allclose(to_torch(bs.wo)[front], to_torch(bs_b.wo)[front], atol=1e-5)
    assert torch.allclose(to_torch(bs.pdf), to_torch(bs_b.pdf), rtol=1e-4, atol=1e-7)
    assert torch.allclose(to_torch(weight), to_torch(weight_b), rtol=1e-4, atol=1e-6)
    assert bool((to_torch(weight)[viewer[:, 2] <= 0] == 0).all())


@pytest.mark.parametrize("theta", [0.3, 1.2])
def test_mitsuba_chi2_accepts_the_native_sampler(mi, nmat, theta):
    """Symbolic mode (Mitsuba's default), as the native BSDF renders."""
    test = bsdf_chi2_test(mi, mi.load_dict({"type": "neumat", "filename": str(nmat)}), theta)
    assert test.run(), test.messages


def test_native_render_equals_the_bridge_render(mi, nmat):
    """The same warps on the same random numbers: the same image up to float error; the native scene renders in
    symbolic mode (`render` picks it), where the bridge could only give NaN."""
    import drjit as dr
    from neumat.integrations import mitsuba as plugin
    native_scene = sphere_scene(mi, {"type": "neumat", "filename": str(nmat)})
    assert not plugin.needs_evaluated_mode(native_scene)
    assert dr.flag(dr.JitFlag.SymbolicCalls)
    ours = torch.from_numpy(np.array(mi.render(native_scene), dtype=np.float32))  # plain Mitsuba, symbolic
    bridge_scene = sphere_scene(mi, {"type": "neumat", "filename": str(nmat), "native": False})
    assert plugin.needs_evaluated_mode(bridge_scene)
    theirs = plugin.render(bridge_scene)
    assert bool(torch.isfinite(ours).all()) and float(ours.mean()) > 0
    close = ((ours - theirs).abs() <= 1e-3 * theirs.abs() + 1e-4).all(-1)
    assert float(close.float().mean()) > 0.99, float(close.float().mean())
    assert abs(float(ours.mean() / theirs.mean()) - 1) < 1e-3
    again = plugin.render(native_scene)  # neumat's render: symbolic for this scene, the same image
    assert torch.allclose(again, ours)


_NO_TORCH = """
import sys
from neumat.integrations import mitsuba_native
mi = mitsuba_native.register()
import numpy as np
bsdf = {{"type": "neumat", "filename": {path!r}}}
scene = mi.load_dict({{"type": "scene", "integrator": {{"type": "path", "max_depth": 3}},
    "sensor": {{"type": "perspective", "film": {{"type": "hdrfilm", "width": 8, "height": 8}},
               "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 3], target=[0, 0, 0], up=[0, 1, 0]),
               "sampler": {{"type": "independent", "sample_count": 4}}}},
    "sphere": {{"type": "sphere", "bsdf": bsdf}}, "sky": {{"type": "constant"}}}})
image = np.array(mi.render(scene))
assert np.isfinite(image).all() and image.mean() > 0, image.mean()
print("torch imported:", "torch" in sys.modules)
"""


def test_a_native_render_imports_no_torch(mi, nmat, tmp_path):
    from neumat.catalog.modelfile import load_model
    from neumat.export.registry import load_formats
    fmt = load_formats().get("drjit")
    folder, _ = fmt.write(fmt.export(load_model(nmat), "fp16"), tmp_path)
    env = {**os.environ, "PYTHONPATH": SRC + os.pathsep + os.environ.get("PYTHONPATH", "")}
    run = subprocess.run([sys.executable, "-c", _NO_TORCH.format(path=str(folder))], capture_output=True, text=True,
                         env=env, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    assert "torch imported: False" in run.stdout, run.stdout + run.stderr[-2000:]


_CUDA = """
import json, sys
import numpy as np
from neumat.integrations import mitsuba_native
mi = mitsuba_native.register("cuda_ad_rgb")
import drjit as dr
wi, wo = (np.array(a, dtype=np.float32) for a in json.loads(sys.stdin.read()))
bsdf = mi.load_dict({{"type": "neumat", "filename": {path!r}}})
si = dr.zeros(mi.SurfaceInteraction3f, wi.shape[0])
si.wi = mi.Vector3f(*(mi.Float(c) for c in wi.T))
value = np.array(bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(*(mi.Float(c) for c in wo.T))))
print(json.dumps(value.tolist()))
"""


@pytest.mark.cuda
def test_native_bsdf_under_cuda_ad_rgb(nmat):
    """The same BSDF under cuda_ad_rgb (fp16 compute, cooperative vectors on tensor cores) against the torch model in
    float64 (times the light's cosine, as Mitsuba's eval), within the fp16 bound (1e-2 relative); in a subprocess,
    since a process holds one Mitsuba variant at a time here. Needs no LLVM: a GPU machine without LLVM >= 16 runs
    it."""
    import json
    from importlib.util import find_spec
    from neumat.catalog.modelfile import load_model
    from neumat.core.query import Query
    if find_spec("mitsuba") is None:
        pytest.skip("needs Mitsuba 3 (pip install mitsuba)")
    g = torch.Generator().manual_seed(7)
    wi, wo = _dirs(4096, g, below=0.0), _dirs(4096, g, below=0.0)
    with torch.no_grad():
        # Mitsuba's eval is the BRDF times the light's cosine; its si.wi is the viewer, the torch Query's wi
        expected = load_model(nmat, device="cpu").double().eval(Query(wi.double(), wo.double())) * wo[:, 2:].double()
    env = {**os.environ, "PYTHONPATH": SRC + os.pathsep + os.environ.get("PYTHONPATH", "")}
    run = subprocess.run([sys.executable, "-c", _CUDA.format(path=str(nmat))], capture_output=True, text=True,
                         env=env, timeout=600, input=json.dumps([wi.tolist(), wo.tolist()]))
    assert run.returncode == 0, run.stderr[-3000:]
    got = torch.tensor(json.loads(run.stdout.strip().splitlines()[-1]), dtype=torch.float64).T
    assert float(expected.abs().min()) > 0  # every pair above the horizon: no vacuous zeros
    assert float(((got - expected).abs() / expected.abs()).max()) < 1e-2


@pytest.fixture(scope="module")
def ggx_nmat(tmp_path_factory) -> Path:
    """A fitted-GGX file (anisotropic, coloured diffuse): the baseline that samples itself."""
    from neumat.methods.baselines.ggx import GGXFit
    model = GGXFit(anisotropic=True)
    with torch.no_grad():
        model.raw_alpha.copy_(torch.tensor([-1.5, -0.5]))
        model.raw_diffuse.copy_(torch.tensor([0.1, -0.5, -1.0]))
    return save_model(model.train(False), tmp_path_factory.mktemp("native_ggx") / "ggx.nmat")


@pytest.mark.parametrize("theta", [0.3, 1.2])
def test_mitsuba_chi2_accepts_the_native_ggx_sampler(mi, ggx_nmat, theta):
    bsdf = mi.load_dict({"type": "neumat", "filename": str(ggx_nmat)})
    assert "NeumatNativeBSDF" in str(bsdf) and bsdf.runtime.can_sample
    test = bsdf_chi2_test(mi, bsdf, theta)
    assert test.run(), test.messages


def test_native_ggx_render_equals_the_bridge_render(mi, ggx_nmat):
    """The model's own sampler on the same random numbers in both paths: the same image up to float error."""
    from neumat.integrations import mitsuba as plugin
    native_scene = sphere_scene(mi, {"type": "neumat", "filename": str(ggx_nmat)})
    ours = torch.from_numpy(np.array(mi.render(native_scene), dtype=np.float32))
    theirs = plugin.render(sphere_scene(mi, {"type": "neumat", "filename": str(ggx_nmat), "native": False}))
    assert bool(torch.isfinite(ours).all()) and float(ours.mean()) > 0
    close = ((ours - theirs).abs() <= 1e-3 * theirs.abs() + 1e-4).all(-1)
    assert float(close.float().mean()) > 0.98, float(close.float().mean())
    assert abs(float(ours.mean() / theirs.mean()) - 1) < 2e-3


@pytest.fixture(scope="module")
def multiscale_nmat(tmp_path_factory) -> Path:
    """A small spatially varying multi-scale model (shading frame, warps decoded from z_s)."""
    from neumat.methods.latent_mlp.multiscale import MultiScale
    torch.manual_seed(0)
    model = MultiScale(spatial_size=32)
    with torch.no_grad():
        model.mlp.linears()[-1].weight.mul_(0.3)
        model.frame.decode.weight.normal_(0, 0.3)
    return save_model(model.train(False), tmp_path_factory.mktemp("native_ms") / "multiscale.nmat")


def test_a_uv_mapped_model_reads_si_uv_and_the_ray_footprint(mi, multiscale_nmat):
    """eval against the torch model at si.uv with the box-filter footprint of si.duv_dx, si.duv_dy (and at the
    finest level, the bridge's value, where they are zero)."""
    from neumat.catalog.modelfile import load_model
    from neumat.core.query import Query
    model = load_model(multiscale_nmat, device="cpu")
    native = mi.load_dict({"type": "neumat", "filename": str(multiscale_nmat)})
    assert native.runtime.spatially_varying and "NeumatNativeBSDF" in str(native)
    g = torch.Generator().manual_seed(4)
    n = 4000
    viewer, light = _dirs(n, g, below=0.0), _dirs(n, g, below=0.0)
    uv = torch.rand(n, 2, generator=g) * 2 - 0.5
    dx = torch.randn(n, 2, generator=g) * 0.02
    dy = torch.stack([-dx[:, 1], dx[:, 0]], -1) * (0.05 + torch.rand(n, 1, generator=g))  # elongation up to 20
    ctx = mi.BSDFContext()
    for differentials in (False, True):
        si = _si(mi, viewer)
        si.uv = mi.Point2f(mi.Float(uv[:, 0].contiguous()), mi.Float(uv[:, 1].contiguous()))
        footprint = None
        if differentials:
            si.duv_dx = mi.Vector2f(mi.Float(dx[:, 0].contiguous()), mi.Float(dx[:, 1].contiguous()))
            si.duv_dy = mi.Vector2f(mi.Float(dy[:, 0].contiguous()), mi.Float(dy[:, 1].contiguous()))
            jac = torch.stack([dx, dy], -1)
            footprint = jac @ jac.transpose(1, 2) / 12
        ours = to_torch(native.eval(ctx, si, mi_vector(mi, light)))
        with torch.no_grad():
            ref = model.eval(Query(viewer, light, uv=uv, footprint=footprint)).double() * light[:, 2:3].double()
        err = ((ours - ref).abs() / ref.abs()).max(-1).values
        assert float(err.quantile(0.99)) < 1e-4 and float(err.max()) < 1e-2, (differentials, float(err.max()))
    assert not torch.allclose(ours, to_torch(native.eval(ctx, _si(mi, viewer), mi_vector(mi, light))), rtol=1e-2)


def test_native_multiscale_render_equals_the_bridge_render(mi, multiscale_nmat):
    """Mitsuba's path tracer computes no uv partials: the native path reads the finest level, as the bridge."""
    from neumat.integrations import mitsuba as plugin
    ours = torch.from_numpy(np.array(mi.render(sphere_scene(mi, {"type": "neumat", "filename": str(multiscale_nmat)})),
                                     dtype=np.float32))
    theirs = plugin.render(sphere_scene(mi, {"type": "neumat", "filename": str(multiscale_nmat), "native": False}))
    assert bool(torch.isfinite(ours).all()) and float(ours.mean()) > 0
    close = ((ours - theirs).abs() <= 1e-3 * theirs.abs() + 1e-4).all(-1)
    assert float(close.float().mean()) > 0.98, float(close.float().mean())
    assert abs(float(ours.mean() / theirs.mean()) - 1) < 2e-3


def test_native_neumip_offset_render_equals_the_bridge_render(mi, tmp_path):
    """The "neumip" program (neural offset module and a learned shading frame) through the plugin: the same image as
    the bridge up to float error (finest level in both, as for the multi-scale model)."""
    from neumat.integrations import mitsuba as plugin
    from neumat.methods.latent_mlp.neumip_offset import NeuMIPOffset
    torch.manual_seed(0)
    model = NeuMIPOffset(spatial_size=32, shading_frame=True)
    with torch.no_grad():
        for layer in model.mlp.linears():
            layer.weight.normal_(0, 1.0 / layer.in_features ** 0.5)
        model.frame.decode.weight.normal_(0, 0.3)
        model.offset_mlp.linears()[-1].weight.normal_(0, 1.0)
        model.offset_mlp.linears()[-1].bias.fill_(1.0)
    nmat = save_model(model.train(False), tmp_path / "neumip-offset.nmat")
    native = mi.load_dict({"type": "neumat", "filename": str(nmat)})
    assert "NeumatNativeBSDF" in str(native) and native.runtime.spatially_varying
    ours = torch.from_numpy(np.array(mi.render(sphere_scene(mi, {"type": "neumat", "filename": str(nmat)})),
                                     dtype=np.float32))
    theirs = plugin.render(sphere_scene(mi, {"type": "neumat", "filename": str(nmat), "native": False}))
    assert bool(torch.isfinite(ours).all()) and float(ours.mean()) > 0
    close = ((ours - theirs).abs() <= 1e-3 * theirs.abs() + 1e-4).all(-1)
    assert float(close.float().mean()) > 0.98, float(close.float().mean())
    assert abs(float(ours.mean() / theirs.mean()) - 1) < 2e-3


def test_a_model_whose_sampler_has_no_native_form_keeps_the_bridge(mi, tmp_path, monkeypatch):
    """A model with a learned sampler whose runtime cannot sample (here neural-appearance's program with its sampler
    switched off): its model file renders through the bridge (with the sampler), its drjit export natively
    (cosine-weighted sampling). neural-appearance itself samples natively
    (tests/integrations/test_mitsuba_native_neural_appearance.py)."""
    from neumat.export.drjit.format import export_drjit
    from neumat.export.drjit.runtime import PROGRAMS
    from neumat.methods.neural_appearance.model import NeuralAppearance
    torch.manual_seed(0)
    model = NeuralAppearance(spatial_size=8).runtime().train(False)
    nmat = save_model(model, tmp_path / "na.nmat")
    assert "NeumatNativeBSDF" in str(mi.load_dict({"type": "neumat", "filename": str(nmat)}))
    monkeypatch.setattr(PROGRAMS["neural-appearance"], "can_sample", False)
    assert "NeumatBSDF[" in str(mi.load_dict({"type": "neumat", "filename": str(nmat)}))
    folder = export_drjit(model).write(tmp_path / "drjit")
    native = mi.load_dict({"type": "neumat", "filename": str(folder)})
    assert "NeumatNativeBSDF" in str(native) and not native.runtime.can_sample
