"""`read_as_images`: the textures an export fetches texel by texel are images under GLSL 4.20 and samplers below,
and every family computes the same under both."""
import numpy as np
import pytest
import torch

from neumat.export.glsl import export_glsl
from neumat.export.glsl_common import (GLSL_IMAGE_VERSION, GLSL_VERSION, MAX_IMAGES, GLSLExport, glsl_version_number,
                                      read_as_images)
from neumat.fit.footprint_queries import footprint_queries
from neumat.models.registry import build_model
from neumat.core.errors import InputError
from neumat.testing import parity
from neumat.testing.parity import glsl_eval, opengl_available

needs_gl = pytest.mark.skipif(not opengl_available(), reason="no moderngl or no headless OpenGL 3.3 context (EGL)")


def test_version_lines_parse_and_anything_else_is_refused():
    assert glsl_version_number(GLSL_VERSION) == 330 and glsl_version_number("#version 450") == 450
    for bad in ("330", "#version", "#version four", "#version 330 core extra", None):
        with pytest.raises(InputError, match="expected a #version line"):
            glsl_version_number(bad)


def _texture(dtype=np.float32) -> np.ndarray:
    return np.zeros((1, 2, 2, 4), dtype)


def test_only_textures_read_by_texel_fetch_at_level_0_become_images():
    source = """uniform sampler2DArray a;
uniform sampler2DArray b;
uniform sampler2DArray c;
uniform sampler2DArray d;
// a comment naming c does not count
vec4 f(ivec2 p) {
    return texelFetch(a, ivec3(p.x + 1, p.y, 0), 0) + texelFetch(b, ivec3(p, 0), 0)
        + texelFetch(c, ivec3(p, 0), 0) * float(textureSize(c, 0).z) + texelFetch(d, ivec3(p, 0), 1);
}"""
    export = read_as_images(GLSLExport(source, {"a": _texture(), "b": _texture(np.float16), "c": _texture(),
                                                "d": _texture()}, False))
    assert export.images == {"a": 0, "b": 1}  # c's size is queried, d is read at level 1: samplers still
    assert export.fastest_glsl_version() == GLSL_IMAGE_VERSION
    out = export.source
    assert "layout(rgba32f, binding = 0) readonly uniform image2DArray a;" in out
    assert "layout(rgba16f, binding = 1) readonly uniform image2DArray b;" in out  # a float16 texture's format
    assert "nm_texel_a(ivec3(p.x + 1, p.y, 0)) + nm_texel_b(ivec3(p, 0))" in out
    assert out.count("#if __VERSION__ >= 420") == 2 and "uniform sampler2DArray c;\nuniform sampler2DArray d;" in out
    assert "texelFetch(c, ivec3(p, 0), 0)" in out and "texelFetch(d, ivec3(p, 0), 1)" in out
    assert read_as_images(export).source == out  # applying it twice changes nothing
    none = read_as_images(GLSLExport("vec3 neumat_eval(vec3 wi, vec3 wo) { return wi; }", {}, False))
    assert none.images == {} and none.fastest_glsl_version() == GLSL_VERSION


def test_at_most_max_images_textures_become_images():
    names = [f"t{i}" for i in range(MAX_IMAGES + 2)]
    source = "".join(f"uniform sampler2DArray {n};\n" for n in names) + "vec4 f(ivec3 p) { return " + \
        " + ".join(f"texelFetch({n}, p, 0)" for n in names) + "; }"
    export = read_as_images(GLSLExport(source, {n: _texture() for n in names}, False))
    assert export.images == {n: i for i, n in enumerate(names[:MAX_IMAGES])}
    assert f"texelFetch({names[-1]}, p, 0)" in export.source


#: one small model of each family with a GLSL export that reads textures (SparseBTF: its web viewer and Slang
#: tests read its samplers, its GLSL tests its images; NeuPreSS: its weight texture's size is queried, a sampler)
FAMILIES = {
    "multiscale": {"type": "multiscale", "spatial_size": 16},
    "tripleplane": {"type": "tripleplane", "spatial_size": 16},
    "neumip": {"type": "neumip", "spatial_size": 16},
    "neumip-frame": {"type": "neumip-frame", "spatial_size": 16},
    "neumip-offset": {"type": "neumip-offset", "spatial_size": 16},
    "nbrdf-uv": {"type": "nbrdf-uv", "spatial_size": 16, "directions": "cartesian"},
    "neural-appearance": {"type": "neural-appearance", "spatial_size": 16},
    "neubrdf": {"type": "neubrdf", "nside": 4, "index_bits": 4, "hidden": 16},
    "neubrdf (first-layer table)": {"type": "neubrdf", "nside": 4, "index_bits": 4, "hidden": 16,
                                    "interpolation": "uniform"},
}


@needs_gl
@pytest.mark.parametrize("precision", ["fp16", "fp32"])
@pytest.mark.parametrize("name", FAMILIES)
def test_every_family_computes_the_same_with_images_and_with_samplers(name, precision):
    torch.manual_seed(0)
    model = build_model(FAMILIES[name]).train(False)
    export = export_glsl(model, precision)
    assert export.images and export.fastest_glsl_version() == GLSL_IMAGE_VERSION
    q = footprint_queries(model, model)(512, torch.Generator().manual_seed(1), torch.device("cpu"))
    images, samplers = glsl_eval(export, q), glsl_eval(export, q, version=GLSL_VERSION)
    assert bool(torch.isfinite(images).all()) and float(images.abs().max()) > 0
    scale = images.abs().clamp(min=1e-6 * float(images.abs().max()))
    assert float(((images - samplers).abs() / scale).max()) < 1e-6, name


@needs_gl
def test_an_opengl_below_4_2_runs_the_samplers(monkeypatch):
    """By default `glsl_eval` compiles under the export's fastest GLSL; a context below 4.2 (macOS's 4.1, here the
    same context reporting 410) runs the GLSL 3.30 form instead, and refuses 4.20 asked for by name."""
    torch.manual_seed(0)
    model = build_model(FAMILIES["multiscale"]).train(False)
    export = export_glsl(model, "fp32")
    q = footprint_queries(model, model)(256, torch.Generator().manual_seed(1), torch.device("cpu"))
    samplers = glsl_eval(export, q, version=GLSL_VERSION)
    make = parity._context

    class Older:
        version_code = 410

        def __init__(self, ctx):
            self._ctx = ctx

        def __getattr__(self, name):
            return getattr(self._ctx, name)

    def older(backend):
        moderngl, ctx = make(backend)
        return moderngl, Older(ctx)
    monkeypatch.setattr(parity, "_context", older)
    assert torch.equal(glsl_eval(export, q), samplers)
    with pytest.raises(InputError, match="cannot compile '#version 420 core'"):
        glsl_eval(export, q, version=GLSL_IMAGE_VERSION)
