"""neural-appearance through the native Mitsuba BSDF (`neumat.integrations.mitsuba_native`): its .nmat renders on
the Dr.Jit runtime with its own learned sampler (program "neural-appearance"): the plugin picks the native path;
sample / pdf / eval_pdf against the torch bridge on the same random numbers; Mitsuba's chi2 test of the sampler at
a uv; a render equal to the bridge's within float error; no torch import while loading and rendering its drjit
export."""
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
from neumat.methods.neural_appearance.model import NeuralAppearance
from test_mitsuba_native import _NO_TORCH, SRC, _dirs, _si

pytestmark = pytest.mark.mitsuba


@pytest.fixture(scope="module")
def mi():
    from mitsuba_util import mitsuba_or_skip
    mitsuba_or_skip()
    from neumat.integrations import mitsuba as plugin
    return plugin.register()


@pytest.fixture(scope="module")
def na_nmat(tmp_path_factory) -> Path:
    """A small neural-appearance model in its runtime form, sampler lobes that vary with wi and the latent."""
    torch.manual_seed(0)
    model = NeuralAppearance(spatial_size=16)
    with torch.no_grad():
        model.mlp.linears()[-1].weight.mul_(0.3)
        model.mlp.linears()[-1].bias.fill_(-1.0)
        model.frame.decode.weight.normal_(0, 0.3)
        for layer in model.sampler.mlp.linears():
            layer.weight.normal_(0, 1.0 / layer.in_features ** 0.5)
    return save_model(model.train(False).runtime(), tmp_path_factory.mktemp("native_na") / "na.nmat")


def _uv(mi, si, uv):
    si.uv = mi.Point2f(mi.Float(uv[:, 0].contiguous()), mi.Float(uv[:, 1].contiguous()))
    return si


def test_the_plugin_renders_neural_appearance_natively_with_its_sampler(mi, na_nmat):
    bsdf = mi.load_dict({"type": "neumat", "filename": str(na_nmat)})
    assert "NeumatNativeBSDF" in str(bsdf) and bsdf.runtime.can_sample and bsdf.runtime.spatially_varying
    assert bsdf.runtime.manifest["program"] == "neural-appearance"


def test_sample_pdf_eval_pdf_match_the_torch_bridge(mi, na_nmat):
    native = mi.load_dict({"type": "neumat", "filename": str(na_nmat)})
    bridge = mi.load_dict({"type": "neumat", "filename": str(na_nmat), "native": False})
    g = torch.Generator().manual_seed(3)
    n = 4000
    viewer, light = _dirs(n, g), _dirs(n, g)
    uv = torch.rand(n, 2, generator=g)
    u = torch.rand(n, 3, generator=g)
    for mode in (mi.TransportMode.Radiance, mi.TransportMode.Importance):
        ctx = mi.BSDFContext(mode)
        ours = [to_torch(v) for v in native.eval_pdf(ctx, _uv(mi, _si(mi, viewer), uv), mi_vector(mi, light))]
        theirs = [to_torch(v) for v in bridge.eval_pdf(ctx, _uv(mi, _si(mi, viewer), uv), mi_vector(mi, light))]
        assert torch.allclose(ours[0], theirs[0], rtol=1e-4, atol=1e-7)
        assert torch.allclose(ours[1], theirs[1], rtol=1e-4, atol=1e-7)
        assert torch.allclose(to_torch(native.pdf(ctx, _uv(mi, _si(mi, viewer), uv), mi_vector(mi, light))), ours[1])
        assert torch.allclose(to_torch(native.eval(ctx, _uv(mi, _si(mi, viewer), uv), mi_vector(mi, light))),
                              ours[0], rtol=1e-6, atol=1e-9)
        s1, s2 = mi.Float(u[:, 0].contiguous()), mi.Point2f(mi.Float(u[:, 1].contiguous()),
                                                               mi.Float(u[:, 2].contiguous()))
        bs, weight = native.sample(ctx, _uv(mi, _si(mi, viewer), uv), s1, s2)
        bs_b, weight_b = bridge.sample(ctx, _uv(mi, _si(mi, viewer), uv), s1, s2)
        front = (viewer[:, 2] > 0) & (to_torch(bs_b.pdf) > 0)
        close = (to_torch(bs.wo) - to_torch(bs_b.wo)).abs().amax(-1) < 1e-4
        assert float(close[front].float().mean()) > 0.999
        both = front & close
        assert torch.allclose(to_torch(bs.pdf)[both], to_torch(bs_b.pdf)[both], rtol=1e-3, atol=1e-7)
        good = torch.isclose(to_torch(weight), to_torch(weight_b), rtol=1e-4, atol=1e-6).all(-1)
        assert float(good[both].float().mean()) > 0.995
        assert bool((to_torch(weight)[viewer[:, 2] <= 0] == 0).all())


@pytest.mark.parametrize("theta", [0.3, 1.2])
def test_mitsuba_chi2_accepts_the_native_neural_appearance_sampler(mi, na_nmat, theta):
    """Symbolic mode (Mitsuba's default), at one uv."""
    bsdf = mi.load_dict({"type": "neumat", "filename": str(na_nmat)})
    test = bsdf_chi2_test(mi, bsdf, theta, uv=(0.3, 0.6))
    assert test.run(), test.messages


def test_native_neural_appearance_render_equals_the_bridge_render(mi, na_nmat):
    """The learned sampler on the same random numbers in both paths: the same image up to float error."""
    from neumat.integrations import mitsuba as plugin
    native_scene = sphere_scene(mi, {"type": "neumat", "filename": str(na_nmat)})
    assert not plugin.needs_evaluated_mode(native_scene)
    ours = torch.from_numpy(np.array(mi.render(native_scene), dtype=np.float32))
    theirs = plugin.render(sphere_scene(mi, {"type": "neumat", "filename": str(na_nmat), "native": False}))
    assert bool(torch.isfinite(ours).all()) and float(ours.mean()) > 0
    close = ((ours - theirs).abs() <= 1e-3 * theirs.abs() + 1e-4).all(-1)
    print(f"close {float(close.float().mean()):.4f} mean ratio {float(ours.mean() / theirs.mean()):.6f}", end=" ")
    assert float(close.float().mean()) > 0.98, float(close.float().mean())
    assert abs(float(ours.mean() / theirs.mean()) - 1) < 2e-3


def test_a_native_neural_appearance_render_imports_no_torch(mi, na_nmat, tmp_path):
    from neumat.catalog.modelfile import load_model
    from neumat.export.registry import load_formats
    fmt = load_formats().get("drjit")
    folder, _ = fmt.write(fmt.export(load_model(na_nmat), "fp16"), tmp_path)
    env = {**os.environ, "PYTHONPATH": SRC + os.pathsep + os.environ.get("PYTHONPATH", "")}
    run = subprocess.run([sys.executable, "-c", _NO_TORCH.format(path=str(folder))], capture_output=True, text=True,
                         env=env, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    assert "torch imported: False" in run.stdout, run.stdout + run.stderr[-2000:]
