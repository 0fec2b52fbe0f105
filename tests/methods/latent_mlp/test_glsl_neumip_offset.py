"""Parity of the GLSL and Slang exports of NeuMIP's neural offset module (`neumip-offset`, Config.offset) with the
torch model: the offset pyramid, the offset MLP and the parallax uv' = uv + h wo.xy / max(wo.z, offset_min_cos)
(EGL / llvmpipe and slangpy's CPU device).

The test models' offset MLP outputs a depth of about 3 finest-level texels (its last layer moved off its start
at 0), so lookups move by several texels (median ~7, up to ~60 at grazing wo): the model read at the unshifted uv
is far from the shifted one, and an export that ignored the offset would fail. Bounds are those of the neumip
parity tests: GLSL fp32 1e-4 (`test_glsl_latent_mlp`), Slang 5e-5 (`test_slang`), fp16 5e-5 from `half_rounded`
and 2e-3 from the fp32 model (`test_half_precision`). Measured: 8e-7 to 2.8e-6 on both, fp32 and fp16; the fp16
export 1.1e-3 from the fp32 model; the model read at the unshifted uv 6.8e-2 to 1.1e-1 from the shifted one."""
import copy

import numpy as np
import pytest
import torch

from neumat.core.query import Query
from neumat.export.glsl import export_glsl
from neumat.export.slang import export_slang
from neumat.export.web.headless import chromium, viewer_pixels
from neumat.export.web.scene import View, viewer_image, viewer_queries
from neumat.export.web.viewer import write_viewer
from neumat.models.half_precision import half_rounded
from neumat.models.registry import build_model
from neumat.testing.parity import glsl_eval, opengl_available
from neumat.testing.slang_parity import SlangKernel, slang_available, slang_eval
from test_glsl_latent_mlp import _queries

needs_gl = pytest.mark.skipif(not opengl_available(), reason="no moderngl or no headless OpenGL 3.3 context (EGL)")
needs_slang = pytest.mark.skipif(not slang_available(), reason="slangpy is not installed or its CPU device "
                                                               "cannot be created (pip install slangpy)")
needs_browser = pytest.mark.skipif(chromium() is None, reason="no chromium on PATH (Debian: apt-get install chromium)")
GLSL_TOL, SLANG_TOL, HALF_TOL, FP32_TOL = 1e-4, 5e-5, 5e-5, 2e-3
CONFIGS = {
    "neumip-offset": {"type": "neumip-offset", "spatial_size": 16},
    "roulette": {"type": "neumip-offset", "spatial_size": 16, "level_selection": "roulette"},
    "neumip-frame + offset": {"type": "neumip-frame", "spatial_size": 16, "spatial_channels": 6, "offset": True},
}
DEPTH = 3.0
"""Bias of the offset MLP's output: the depth in finest-level texels, about."""


def _model(spec: dict):
    """The model with every parameter moved off its start and a depth of about DEPTH texels."""
    torch.manual_seed(1)
    model = build_model(spec).train(False)
    with torch.no_grad():
        for p in model.parameters():
            p.add_(0.1 * torch.randn_like(p))
        last = model.offset_mlp.linears()[-1]
        last.weight.mul_(10)  # the depth varies over the texture and with wo by ~1 texel
        last.bias.fill_(DEPTH)
    return model


def _relative(got: torch.Tensor, ref: torch.Tensor) -> float:
    return float(((got - ref).abs() / ref.abs().clamp(min=1e-6)).max())


def _reference(model, q: Query) -> tuple[torch.Tensor, torch.Tensor]:
    """The model's eval at q, and its eval with the lookup left at uv (the offset module's depth set to 0), after
    checking that the offset moves the lookups by several texels."""
    with torch.no_grad():
        shift = (model.offset_uv(q, q.footprint) - q.uv).norm(dim=-1) * model.cfg.spatial_size
        assert float(shift.median()) > 3, "the test needs lookups moved by several texels"
        still = copy.deepcopy(model)
        still.offset_mlp.start_constant(torch.zeros(1))
        return model.eval(q), still.eval(q)


@needs_gl
@pytest.mark.parametrize("name", CONFIGS)
@pytest.mark.parametrize("footprint", [True, False], ids=["footprint", "lod"])
def test_glsl_offset_eval_matches_torch(name, footprint):
    model = _model(CONFIGS[name])
    q = _queries(1024, footprint)
    ref, unshifted = _reference(model, q)
    out = glsl_eval(export_glsl(model, "fp32"), q)
    assert _relative(out, ref) < GLSL_TOL, f"{name}: max relative error {_relative(out, ref):.2e}"
    assert _relative(unshifted, ref) > 100 * GLSL_TOL, "the offset changes the values"


@needs_gl
def test_glsl_fp16_offset_eval_matches_half_rounded_model():
    model = _model(CONFIGS["neumip-offset"])
    q = _queries(1024, True)
    with torch.no_grad():
        ref, half = model.eval(q), half_rounded(model).eval(q)
    export = export_glsl(model)
    assert export.precision == "fp16" and set(export.textures) == {"neumat_spatial", "neumat_offset"}
    out = glsl_eval(export, q)
    assert _relative(out, half) < HALF_TOL, f"{_relative(out, half):.2e} from half_rounded"
    assert _relative(out, ref) < FP32_TOL, f"{_relative(out, ref):.2e} from the fp32 model"


@needs_slang
@pytest.mark.parametrize("precision", ["fp32", "fp16"])
def test_slang_offset_eval_matches_torch(precision):
    model = _model(CONFIGS["roulette" if precision == "fp32" else "neumip-offset"])
    kernel = SlangKernel(export_slang(model, precision))
    reference = model if precision == "fp32" else half_rounded(model)
    for footprint in (True, False):
        q = _queries(1024, footprint)
        q.wi[::16, 2] *= -1  # below the horizon: 0
        ref, unshifted = _reference(reference, q)
        out = slang_eval(kernel, q)
        assert torch.equal(out[::16], torch.zeros_like(out[::16]))
        rel = _relative(out, ref)
        assert rel < SLANG_TOL, f"{precision} {'footprint' if footprint else 'lod'}: max relative error {rel:.2e}"
        assert _relative(unshifted, ref) > 100 * SLANG_TOL, "the offset changes the values"


def test_offset_export_carries_the_offset_pyramid_and_mlp():
    """Without a GL context: the offset pyramid is a second atlas (`neumat_offset`) laid out as the spatial one
    (channel c in layer c // 4, component c % 4, the finest level at the origin), halves at fp16; the offset MLP's
    weights are constants of the source; Slang carries the same buffers."""
    model = _model(CONFIGS["neumip-offset"])
    full, half = export_glsl(model, "fp32"), export_glsl(model)
    spatial, offset = full.textures["neumat_spatial"], full.textures["neumat_offset"]
    assert offset.shape == (2, *spatial.shape[1:])  # 5 channels in 2 layers
    texels = torch.from_numpy(offset[:, :16, :16]).permute(0, 3, 1, 2).reshape(8, 16, 16)
    with torch.no_grad():
        assert torch.equal(texels[:5], model.offset_texture.levels()[0]) and not texels[5:].any()
    assert half.textures["neumat_offset"].dtype == np.float16
    assert 2 * half.storage_bytes()["total"] == full.storage_bytes()["total"]
    weights = model.offset_mlp.linears()[0].weight.detach()
    assert f"const float NM_O0_W[{weights.numel()}] = float[]({float(weights[0, 0]):.9e}, " in full.source
    assert "vec2 nm_parallax(vec3 wo, vec2 uv, mat2 footprint)" in full.source
    option = export_slang(_model({"type": "neumip", "spatial_size": 16, "offset": True}), "fp32")
    assert set(option.buffers) == {"neumat_spatial", "neumat_offset"}


@needs_browser
def test_web_viewer_renders_the_offset_module(tmp_path):
    """The page (WebGL 2, headless Chromium) renders what torch gives on a tilted plane, where wo leans and the
    lookups move; 1 / 8 texel per pixel keeps the page's dFdx / dFdy filter at the finest level, as the torch
    scene's footprint-free queries (`test_web_viewer`'s bound for a filtered export)."""
    model = _model(CONFIGS["neumip-offset"])
    view = View(shape="plane", pitch=-0.6)
    q, valid = viewer_queries(view, 96, 96)
    q = Query(wi=q.wi[valid], wo=q.wo[valid], uv=q.uv[valid])
    with torch.no_grad():
        assert float((model.offset_uv(q, None) - q.uv).norm(dim=-1).median()) * 16 > 1
    page = write_viewer(model, tmp_path / "offset.html")
    pixels, reference = viewer_pixels(page, view, 96, 96)[..., :3], viewer_image(half_rounded(model), view, 96, 96)
    covered = reference.amax(-1) > 0
    error = (pixels - reference).abs()[covered] / reference[covered].abs().clamp(min=1e-6)
    assert float(error.median()) < 1e-3, f"median relative difference {float(error.median()):.2e}"
