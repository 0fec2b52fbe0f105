"""Parity of the GLSL export of the multi-scale models with the torch model (run on EGL / llvmpipe)."""
import json

import numpy as np
import pytest
import torch

from neumat.core.errors import InputError
from neumat.core.query import Query
from neumat.export.glsl import export_glsl
from neumat.models.registry import build_model
from neumat.nn import cpu_kernels

from neumat.testing.parity import glsl_eval, opengl_available

needs_gl = pytest.mark.skipif(not opengl_available(), reason="no moderngl or no headless OpenGL 3.3 context (EGL)")

CONFIGS = {
    "gated": {"type": "multiscale", "spatial_size": 16},
    "tripleplane": {"type": "tripleplane", "spatial_size": 16},
    "homogeneous": {"type": "multiscale", "homogeneous": True},
    # odd sizes: 6 latent channels (a partly used texture layer), 37 azimuths, concatenation with a frame
    "odd": {"type": "multiscale", "spatial_size": 8, "spatial_channels": 6, "angular_phi": 37, "gating": False},
}


def _model(spec: dict):
    torch.manual_seed(1)
    model = build_model(spec).train(False)
    with torch.no_grad():  # move frame, warps and decoders away from their initial (identity-like) values
        for p in model.parameters():
            p.add_(0.05 * torch.randn_like(p))
    return model


def _queries(n: int, min_cos: float, spatial: bool, footprint: bool) -> Query:
    g = torch.Generator().manual_seed(2)

    def direction():
        w = torch.nn.functional.normalize(torch.randn(n, 3, generator=g), dim=-1)
        w[:, 2] = w[:, 2].abs().clamp(min=min_cos)
        return torch.nn.functional.normalize(w, dim=-1)

    wi, wo = direction(), direction()
    if not spatial:
        return Query(wi=wi, wo=wo)
    uv = torch.rand(n, 2, generator=g) * 3 - 1  # tiles on both sides of [0, 1]
    if not footprint:
        return Query(wi=wi, wo=wo, uv=uv, lod=torch.rand(n, generator=g) * 7 - 1)
    a = torch.randn(n, 2, 2, generator=g) * torch.exp2(torch.rand(n, 1, 1, generator=g) * -8)
    return Query(wi=wi, wo=wo, uv=uv, footprint=a @ a.transpose(1, 2) + 1e-8 * torch.eye(2))


def _relative_error(model, q):
    with torch.no_grad(), cpu_kernels.switched_off():  # the torch formulas the shader translates
        ref = model.eval(q)
    out = glsl_eval(export_glsl(model, "fp32"), q)
    return ((out - ref).abs() / ref.abs().clamp(min=1e-6)).max(-1).values


@needs_gl
@pytest.mark.parametrize("name", CONFIGS)
@pytest.mark.parametrize("footprint", [True, False], ids=["footprint", "lod"])
def test_glsl_matches_torch(name, footprint):
    spec = CONFIGS[name]
    model = _model(spec)
    if footprint is False and not model.spatially_varying:
        pytest.skip("a homogeneous model has no lod")
    # away from grazing angles both are float32 evaluations of the same formulas
    rel = _relative_error(model, _queries(2048, 0.1, model.spatially_varying, footprint))
    assert float(rel.max()) < 1e-4, f"{name}: max relative error {float(rel.max()):.2e}"
    # at grazing angles the lift z = sqrt(1 - x^2 - y^2) loses ~eps / z^2 (about 1e-3 at z = 0.01)
    rel = _relative_error(model, _queries(2048, 0.0, model.spatially_varying, footprint))
    assert float(rel.max()) < 1e-2 and float(rel.median()) < 1e-5, name


@needs_gl
@pytest.mark.parametrize("name", ["gated", "tripleplane"])
def test_glsl_applies_the_output_bound(name):
    model = _model(CONFIGS[name])
    q = _queries(2048, 0.1, True, True)
    with torch.no_grad():  # a bound below most outputs, so that the clamp is exercised
        model.target_max.copy_(model.eval(q).median(0).values)
    source = export_glsl(model, "fp32").source
    assert "min(exp(" in source
    out, bound = glsl_eval(export_glsl(model, "fp32"), q), model.target_max
    assert bool((out == bound).any()) and bool((out <= bound * (1 + 1e-6)).all())
    assert float(_relative_error(model, q).max()) < 1e-4


@needs_gl
def test_glsl_is_zero_below_the_horizon():
    model = _model(CONFIGS["homogeneous"])
    q = Query(wi=torch.tensor([[0.0, 0.6, -0.8], [0.0, 0.0, 1.0]]),
              wo=torch.tensor([[0.0, 0.0, 1.0], [0.6, 0.0, -0.8]]))
    assert torch.equal(glsl_eval(export_glsl(model), q), torch.zeros(2, 3))


def test_write_files_and_manifest(tmp_path):
    model = _model(CONFIGS["gated"])
    export = export_glsl(model, "fp32")
    export.write(tmp_path / "out")
    manifest = json.loads((tmp_path / "out" / "manifest.json").read_text())
    assert (tmp_path / "out" / "neumat.glsl").read_text() == export.source
    assert "vec3 neumat_eval(vec3 wi, vec3 wo, vec2 uv, mat2 footprint)" in export.source
    assert set(manifest["textures"]) == {"neumat_spatial", "neumat_half", "neumat_diff"}
    for name, info in manifest["textures"].items():
        data = np.fromfile(tmp_path / "out" / info["file"], "<f4").reshape(info["layers"], info["height"],
                                                                          info["width"], 4)
        assert np.array_equal(data, export.textures[name])
    # 8 x 8 matrices over 16 x 40 texels: 64 channels in 16 layers, values as the preconditioned texture
    half = export.textures["neumat_half"]
    assert half.shape == (16, 16, 40, 4)
    with torch.no_grad():
        tex = model.half_texture.texture()
    np.testing.assert_array_equal(half[3, 5, 7, 2], tex[14, 5, 7].numpy())


def test_bad_input():
    with pytest.raises(InputError, match="multi-scale model"):
        export_glsl(build_model({"type": "nbrdf"}))
    model = build_model({"type": "multiscale", "homogeneous": True})
    with torch.no_grad():
        model.mlp.linears()[0].weight[0, 0] = float("nan")
    with pytest.raises(InputError, match="non-finite"):
        export_glsl(model)
