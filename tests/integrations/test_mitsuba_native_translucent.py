"""NeuPreSS on the Dr.Jit runtime (program "neupress", `neumat.export.drjit.neupress`) and the scene integrator's
native path (`neumat.integrations.mitsuba_translucent`): S_hat, sigma, the incident pdf and sampled directions equal
the torch model's on random queries (fp32, <= 1e-4 relative); the integrator picks the native path for a NeuPreSS
and keeps torch on request; a render through the native path equals the torch path's within noise; no torch import
while loading and rendering a drjit export."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from neumat.core.query import Query

pytestmark = pytest.mark.mitsuba

SRC = str(Path(__file__).resolve().parents[2] / "src")
RES = 16


@pytest.fixture(scope="module")
def mi():
    from mitsuba_util import mitsuba_or_skip
    mitsuba_or_skip()
    from neumat.integrations import mitsuba_translucent as nt
    return nt.register()


def _nt():
    from neumat.integrations import mitsuba_translucent as nt
    return nt


def _model(lo=(-1.0,) * 3, hi=(1.0,) * 3, **kwargs):
    """A small NeuPreSS with random weights, sigma spread over its whole range."""
    from neumat.methods.neupress.model import NeuPreSS
    torch.manual_seed(0)
    m = NeuPreSS(**{**dict(features=16, width=16, layers=3, sampler_hidden=(8, 4)), **kwargs})
    m.set_bounds(torch.as_tensor(lo, dtype=torch.float32), torch.as_tensor(hi, dtype=torch.float32))
    with torch.no_grad():
        m.appearance.out.bias.add_(0.3)
        for layer in m.sampler:
            if isinstance(layer, torch.nn.Linear):
                layer.weight.mul_(3)
    return m.train(False)


def _dirs(n, g):
    v = torch.randn(n, 3, generator=g)
    return v / v.norm(dim=-1, keepdim=True)


def _vec(mi, t):
    return mi.Vector3f(*(mi.Float(t[:, i].float().contiguous().numpy()) for i in range(3)))


def _t(v) -> torch.Tensor:
    a = np.array(v, dtype=np.float32)
    return torch.from_numpy(a.T.copy() if a.ndim == 2 and a.shape[0] == 3 else a)


@pytest.mark.parametrize("encoding,skips", [("spherical", True), ("cartesian", False)])
def test_runtime_matches_torch_on_random_queries(mi, encoding, skips, tmp_path):
    from neumat.export.drjit.runtime import load_runtime
    from neumat.export.registry import load_formats
    model = _model((-1.0, -0.5, -2.0), (1.0, 1.5, 0.3), direction_encoding=encoding, skips=skips)
    fmt = load_formats().get("drjit")
    folder, _ = fmt.write(fmt.export(model, "fp16"), tmp_path)  # halves only where lossless
    rt = load_runtime(folder, mi.Float)
    assert rt.manifest["program"] == "neupress" and rt.translucent
    g = torch.Generator().manual_seed(1)
    n = 4000
    wi, wo, normal = _dirs(n, g), _dirs(n, g), _dirs(n, g)
    x = model.box_min + torch.rand(n, 3, generator=g) * (model.box_max - model.box_min)
    u = torch.rand(n, 2, generator=g)
    with torch.no_grad():
        q = Query(wi=wi, wo=wo, x=x, n=normal)
        f_ref, sigma_ref, pdf_ref = model.eval(q), model.sigma(x, wo), model.incident_pdf(q)
        w_ref, ps_ref = model.sample_incident(q, u)
    f = _t(rt.eval(_vec(mi, wi), _vec(mi, wo), True, x=_vec(mi, x)))
    assert float(((f - f_ref).abs() / f_ref.abs().clamp(min=1e-3)).max()) < 1e-4
    assert float((f_ref > 0).float().mean()) > 0.3  # the clamp at 0 and positive values both exercised
    sigma = _t(rt.sigma(_vec(mi, x), _vec(mi, wo)))
    assert float(((sigma - sigma_ref).abs() / sigma_ref).max()) < 1e-4
    assert float(sigma_ref.min()) < 0.1 and float(sigma_ref.max()) > 3  # narrow and wide lobes
    pdf = _t(rt.incident_pdf(_vec(mi, wi), _vec(mi, x), _vec(mi, wo), _vec(mi, normal)))
    assert float(((pdf - pdf_ref).abs() / pdf_ref.clamp(min=1e-6)).max()) < 1e-4
    w, ps = rt.sample_incident(_vec(mi, x), _vec(mi, wo), _vec(mi, normal), mi.Float(u[:, 0].numpy()),
                               mi.Float(u[:, 1].numpy()))
    w, ps = _t(w), _t(ps)
    assert float((w - w_ref).abs().max()) < 1e-4
    with torch.no_grad():  # the density at the drawn direction is the lobe's pdf there
        at_ours = model.incident_pdf(Query(wi=w / w.norm(dim=-1, keepdim=True), wo=wo, x=x, n=normal))
    assert float(((ps - at_ours).abs() / at_ours.clamp(min=1e-6)).max()) < 1e-4
    # and torch's sampled density: the two drawn directions differ by fp32 rounding (~1e-6), which the density
    # amplifies by theta / sigma^2 in the tails of narrow lobes and by 1 / (pi - theta) at the antipode (measured
    # 1.2e-4 away from the antipode, 5.9e-4 at it)
    away = (w_ref * normal).sum(-1) > -0.99
    assert float(((ps - ps_ref).abs() / ps_ref.clamp(min=1e-6))[away].max()) < 1e-3
    assert float(((ps - ps_ref).abs() / ps_ref.clamp(min=1e-6) < 1e-4).float().mean()) > 0.999


def _props(mi, **kw):
    p = mi.Properties(_nt().PLUGIN_NAME)
    p["shape"] = "translucent"
    for k, v in kw.items():
        p[k] = v
    return p


def test_the_integrator_picks_the_native_path(mi, tmp_path):
    from neumat.catalog.modelfile import save_model
    from neumat.core.errors import InputError
    from neumat.reflectance.translucent import TranslucentConfig
    nt = _nt()
    config = TranslucentConfig()
    path = save_model(_model(), tmp_path / "np.nmat")
    cls = nt._integrator_class(mi)
    assert cls(_props(mi, model=str(path)), source=config).native
    assert cls(_props(mi), model=_model(), source=config).native
    assert not cls(_props(mi, model=str(path), native=False), source=config).native
    # the plain "neumat" BSDF refuses it (it is an object, not a surface)
    with pytest.raises((InputError, RuntimeError), match="neumat_translucent"):  # Mitsuba re-raises plugin errors
        mi.load_dict({"type": "neumat", "filename": str(path)})


def _scene(mi, model, config, native, strategy="mis"):
    nt = _nt()
    from test_mitsuba_translucent import _env, _envmap, _sensor
    integrator = nt._integrator_class(mi)(_props(mi, strategy=strategy, native=native), model=model, source=config)
    sensor = _sensor(mi, (0.5, 1.0, 4.0), (0, 0, 0), (0, 1, 0))
    sensor["film"].update(width=RES, height=RES)
    return mi.load_dict({"type": "scene", "integrator": integrator, "translucent": nt.translucent_shape(config),
                         "light": _envmap(mi, _env()), "sensor": sensor}), integrator


@pytest.mark.parametrize("strategy", ["mis", "light", "model"])
def test_a_native_render_equals_the_torch_render(mi, strategy):
    from neumat.reflectance.translucent import TranslucentConfig
    from test_mitsuba_translucent import _agreement
    nt = _nt()
    config, model = TranslucentConfig(), _model()
    native, it_n = _scene(mi, model, config, True, strategy)
    bridge, it_t = _scene(mi, model, config, False, strategy)
    assert it_n.native and not it_t.native
    a = [nt.render(native, spp=8, seed=s)[..., :3] for s in (0, 1)]
    b = [nt.render(bridge, spp=8, seed=s)[..., :3] for s in (0, 1)]
    on = a[0].abs().amax(-1) > 0
    assert int(on.sum()) > 20
    ratio, bias = _agreement(a, b)
    assert ratio < 1.4 and abs(bias) < 4, (ratio, bias)  # equal within noise ...
    # ... and in fact to float error on most pixels: the same random numbers, fp32 against float64 transforms
    close = ((a[0] - b[0]).abs() <= 1e-3 * b[0].abs().clamp(min=1e-2)).all(-1)
    assert float(close.float().mean()) > 0.95, float(close.float().mean())
    # plain mi.render in Mitsuba's default mode gives the same image (the native path needs no evaluated mode)
    plain = torch.from_numpy(np.array(mi.render(native, spp=8, seed=0), dtype=np.float32))[..., :3]
    assert torch.allclose(plain, a[0], rtol=1e-4, atol=1e-5)


_NO_TORCH = """
import sys
from neumat.integrations import mitsuba_translucent as nt
mi = nt.register()
import numpy as np
shape = {{"type": "sphere", "radius": 1.0, "id": "translucent", "interior": dict(nt.BLACK_MEDIUM),
          "bsdf": {{"type": "roughdielectric", "distribution": "ggx", "alpha": 0.3, "int_ior": 1.5, "ext_ior": 1.0}}}}
scene = mi.load_dict({{"type": "scene",
    "integrator": {{"type": "neumat_translucent", "shape": "translucent", "model": {model!r},
                    "observations": {obs!r}, "integrator": {{"type": "volpath", "max_depth": 8}}}},
    "sensor": {{"type": "perspective", "film": {{"type": "hdrfilm", "width": 8, "height": 8}},
               "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 4], target=[0, 0, 0], up=[0, 1, 0]),
               "sampler": {{"type": "independent", "sample_count": 4}}}},
    "translucent": shape, "sky": {{"type": "constant"}}}})
assert "native" in str(scene.integrator())
image = np.array(mi.render(scene))
assert np.isfinite(image).all() and image.mean() > 0, image.mean()
print("torch imported:", "torch" in sys.modules)
"""


def test_a_native_render_imports_no_torch(mi, tmp_path):
    from dataclasses import asdict

    from neumat.export.registry import load_formats
    from neumat.reflectance.translucent import TranslucentConfig
    fmt = load_formats().get("drjit")
    folder, _ = fmt.write(fmt.export(_model(), "fp16"), tmp_path / "export")
    obs = tmp_path / "obs.npz"  # the object description as `neumat translucent trace` saves it
    np.savez(obs, source=np.array(json.dumps({"object": asdict(TranslucentConfig())})))
    env = {**os.environ, "PYTHONPATH": SRC + os.pathsep + os.environ.get("PYTHONPATH", "")}
    run = subprocess.run([sys.executable, "-c", _NO_TORCH.format(model=str(folder), obs=str(obs))],
                         capture_output=True, text=True, env=env, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    assert "torch imported: False" in run.stdout, run.stdout + run.stderr[-2000:]
