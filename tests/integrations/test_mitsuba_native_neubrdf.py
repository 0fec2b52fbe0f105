"""The native Mitsuba BSDF on the NeuBRDF forms of the "healpix-grid-mlp" program: NeuBRDF with inverse-distance
corner weights, NeuBRDF with a neural texture (reads si.uv), shared-NeuBRDF (its selected material, or the one the
`member` property names). Against the torch bridge on the same .nmat: eval / pdf values, both transport modes;
Mitsuba's chi2 test of the plugin's (cosine-weighted) sampler with each; a render equal to the bridge's within float
error (the same cosine warp on the same random numbers); no torch import while rendering a drjit export."""
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
from neumat.methods.neubrdf.shared_model import SharedNeuBRDF

pytestmark = pytest.mark.mitsuba
SRC = str(Path(__file__).resolve().parents[2] / "src")
SMALL = dict(nside=8, feature_dim=8, index_bits=5, hidden=16)


@pytest.fixture(scope="module")
def mi():
    from mitsuba_util import mitsuba_or_skip
    mitsuba_or_skip()
    from neumat.integrations import mitsuba as plugin
    return plugin.register()


def _brdf_range(model):
    with torch.no_grad():
        last = model.mlp.linears()[-1]
        last.weight.mul_(0.3)
        last.bias.copy_(torch.tensor([-1.0, -1.3, -1.6]))
    return model.train(False).runtime()


@pytest.fixture(scope="module")
def nmats(tmp_path_factory) -> dict[str, Path]:
    """Small runtime-form files, values in a BRDF's range, not reciprocal: "idw" (inverse-distance corner weights),
    "texture" (a 8 x 6 x 3 neural texture, idw), "shared" (three materials, one codebook and MLP)."""
    folder = tmp_path_factory.mktemp("native_neubrdf")
    torch.manual_seed(0)
    idw = _brdf_range(NeuBRDF(**SMALL, direction_inputs="hd_warp", runtime_interpolation="idw"))
    torch.manual_seed(1)
    texture = NeuBRDF(**SMALL, direction_inputs="hd_warp", runtime_interpolation="idw", texture_height=8,
                      texture_width=6, texture_channels=3)
    with torch.no_grad():
        texture.texture.levels[0].mul_(10)  # a texture that shows
    texture = _brdf_range(texture)
    torch.manual_seed(2)
    shared = _brdf_range(SharedNeuBRDF(**SMALL, num_materials=3))
    return {name: save_model(model, folder / f"{name}.nmat")
            for name, model in (("idw", idw), ("texture", texture), ("shared", shared))}


def _dirs(n: int, g: torch.Generator, below: float = 0.1) -> torch.Tensor:
    v = torch.randn(n, 3, generator=g)
    v[:, 2] = v[:, 2].abs() * torch.where(torch.rand(n, generator=g) < below, -1.0, 1.0)
    return v / v.norm(dim=-1, keepdim=True)


def _si(mi, wi: torch.Tensor, uv: torch.Tensor | None = None):
    import drjit as dr
    si = dr.zeros(mi.SurfaceInteraction3f, wi.shape[0])
    si.wi = mi_vector(mi, wi)
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    if uv is not None:
        si.uv = mi.Point2f(mi.Float(uv[:, 0].contiguous()), mi.Float(uv[:, 1].contiguous()))
    return si


@pytest.mark.parametrize("name", ["idw", "texture", "shared"])
def test_eval_and_pdf_match_the_torch_bridge(mi, nmats, name):
    from neumat.integrations import mitsuba as plugin
    native = mi.load_dict({"type": "neumat", "filename": str(nmats[name])})
    bridge = mi.load_dict({"type": "neumat", "filename": str(nmats[name]), "native": False})
    assert "NeumatNativeBSDF" in str(native) and "healpix-grid-mlp" == native.runtime.manifest["program"]
    assert "NeumatBSDF[" in str(bridge)
    assert native.runtime.spatially_varying == (name == "texture")
    g = torch.Generator().manual_seed(3)
    n = 5000
    viewer, light = _dirs(n, g), _dirs(n, g)
    uv = torch.rand(n, 2, generator=g) if name == "texture" else None
    for mode in (mi.TransportMode.Radiance, mi.TransportMode.Importance):
        ctx = mi.BSDFContext(mode)
        with plugin.evaluated_mode():  # the bridge needs it; the native BSDF runs in either mode
            theirs = [to_torch(v) for v in bridge.eval_pdf(ctx, _si(mi, viewer, uv), mi_vector(mi, light))]
        ours = [to_torch(v) for v in native.eval_pdf(ctx, _si(mi, viewer, uv), mi_vector(mi, light))]
        up = (viewer[:, 2] > 0) & (light[:, 2] > 0)
        assert bool(up.any()) and bool((ours[0][~up] == 0).all()) and float(ours[0][up].min()) > 0
        assert torch.allclose(ours[0], theirs[0], rtol=1e-4, atol=1e-7)
        assert torch.allclose(ours[1], theirs[1], rtol=1e-5, atol=1e-7)


def test_the_member_property_selects_a_material_of_a_set(mi, nmats):
    from neumat.catalog.modelfile import load_model
    from neumat.core.query import Query
    model = load_model(nmats["shared"], device="cpu")
    g = torch.Generator().manual_seed(5)
    viewer, light = _dirs(3000, g, below=0.0), _dirs(3000, g, below=0.0)
    ctx = mi.BSDFContext()
    for member in (0, 2):
        bsdf = mi.load_dict({"type": "neumat", "filename": str(nmats["shared"]), "member": member})
        ours = to_torch(bsdf.eval(ctx, _si(mi, viewer), mi_vector(mi, light)))
        with torch.no_grad():
            ref = model.eval_material(member, Query(viewer, light)).double() * light[:, 2:3].double()
        assert torch.allclose(ours, ref, rtol=1e-4, atol=1e-7)
    with pytest.raises(Exception, match="material index"):
        mi.load_dict({"type": "neumat", "filename": str(nmats["shared"]), "member": 3})
    with pytest.raises(Exception, match="holds one material"):
        mi.load_dict({"type": "neumat", "filename": str(nmats["idw"]), "member": 0})


@pytest.mark.parametrize("name", ["idw", "texture", "shared"])
def test_mitsuba_chi2_accepts_the_native_sampler(mi, nmats, name):
    """The plugin samples these models cosine-weighted (none has a learned sampler); symbolic mode."""
    bsdf = mi.load_dict({"type": "neumat", "filename": str(nmats[name])})
    assert not bsdf.runtime.can_sample
    test = bsdf_chi2_test(mi, bsdf, 0.8, uv=(0.3, 0.6) if name == "texture" else None)
    assert test.run(), test.messages


@pytest.mark.parametrize("name", ["texture", "shared"])
def test_native_render_equals_the_bridge_render(mi, nmats, name):
    """Symbolic (native) against the bridge's evaluated render of the same file: the same warps on the same random
    numbers, the same image up to float error (the textured model reads si.uv of the sphere in both)."""
    from neumat.integrations import mitsuba as plugin
    native_scene = sphere_scene(mi, {"type": "neumat", "filename": str(nmats[name])})
    assert not plugin.needs_evaluated_mode(native_scene)
    ours = torch.from_numpy(np.array(mi.render(native_scene), dtype=np.float32))
    theirs = plugin.render(sphere_scene(mi, {"type": "neumat", "filename": str(nmats[name]), "native": False}))
    assert bool(torch.isfinite(ours).all()) and float(ours.mean()) > 0
    close = ((ours - theirs).abs() <= 1e-3 * theirs.abs() + 1e-4).all(-1)
    assert float(close.float().mean()) > 0.99, float(close.float().mean())
    assert abs(float(ours.mean() / theirs.mean()) - 1) < 1e-3


_NO_TORCH = """
import sys
from neumat.integrations import mitsuba_native
mi = mitsuba_native.register()
import numpy as np
scene = mi.load_dict({{"type": "scene", "integrator": {{"type": "path", "max_depth": 3}},
    "sensor": {{"type": "perspective", "film": {{"type": "hdrfilm", "width": 8, "height": 8}},
               "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 3], target=[0, 0, 0], up=[0, 1, 0]),
               "sampler": {{"type": "independent", "sample_count": 4}}}},
    "a": {{"type": "sphere", "center": [-1, 0, 0], "radius": 0.6, "bsdf": {{"type": "neumat", "filename": {a!r}}}}},
    "b": {{"type": "sphere", "center": [1, 0, 0], "radius": 0.6,
          "bsdf": {{"type": "neumat", "filename": {b!r}, "member": 1}}}},
    "sky": {{"type": "constant"}}}})
image = np.array(mi.render(scene))
assert np.isfinite(image).all() and image.mean() > 0, image.mean()
print("torch imported:", "torch" in sys.modules)
"""


def test_a_native_render_of_the_exports_imports_no_torch(mi, nmats, tmp_path):
    from neumat.catalog.modelfile import load_model
    from neumat.export.registry import load_formats
    fmt = load_formats().get("drjit")
    a, _ = fmt.write(fmt.export(load_model(nmats["texture"]), "fp16"), tmp_path / "texture")
    b, _ = fmt.write(fmt.export(load_model(nmats["shared"]), "fp16"), tmp_path / "shared")
    env = {**os.environ, "PYTHONPATH": SRC + os.pathsep + os.environ.get("PYTHONPATH", "")}
    run = subprocess.run([sys.executable, "-c", _NO_TORCH.format(a=str(a), b=str(b))], capture_output=True,
                         text=True, env=env, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    assert "torch imported: False" in run.stdout, run.stdout + run.stderr[-2000:]
