"""The GLSL GGX of the shader speed table (`neumat.testing.glsl_ggx`) computes what the torch GGX computes, in GLSL
and spelled in Slang (`neumat.export.slang.slang_from_glsl`), as does the Slang harness floor."""
import pytest
import torch

from neumat.catalog.open_material import open_material
from neumat.core.errors import InputError
from neumat.core.query import Query
from neumat.export.glsl_common import GLSLExport
from neumat.export.slang import slang_from_glsl
from neumat.testing.glsl_ggx import ggx_glsl
from neumat.testing.parity import glsl_eval, opengl_available
from neumat.testing.slang_parity import slang_available, slang_eval
from neumat.warp.hemisphere import sample_cosine_hemisphere


@pytest.mark.skipif(not opengl_available(), reason="no moderngl or no headless OpenGL 3.3 context (EGL)")
@pytest.mark.parametrize("spec", ["ggx:roughness=0.2", "ggx:alpha_x=0.1,alpha_y=0.4"])
def test_glsl_ggx_matches_torch(spec):
    material = open_material(spec)
    g = torch.Generator().manual_seed(0)
    q = Query(sample_cosine_hemisphere(torch.rand(4096, 2, generator=g)),
              sample_cosine_hemisphere(torch.rand(4096, 2, generator=g)))
    ref = material.eval(q)
    out = glsl_eval(ggx_glsl(material), q)
    assert float(((out - ref).abs() / ref.abs().clamp(min=1e-6)).max()) < 1e-4


def _queries(n: int) -> Query:
    g = torch.Generator().manual_seed(0)
    return Query(sample_cosine_hemisphere(torch.rand(n, 2, generator=g)),
                 sample_cosine_hemisphere(torch.rand(n, 2, generator=g)))


@pytest.mark.skipif(not slang_available("cpu"), reason="no slangpy CPU device (slangpy, a C++ compiler)")
@pytest.mark.parametrize("spec", ["ggx:roughness=0.2", "ggx:alpha_x=0.1,alpha_y=0.4"])
def test_slang_ggx_and_the_floor_match_torch(spec):
    material = open_material(spec)
    q = _queries(2048)
    ref = material.eval(q)
    out = slang_eval(slang_from_glsl(ggx_glsl(material), "ggx"), q)
    assert float(((out - ref).abs() / ref.abs().clamp(min=1e-6)).max()) < 1e-4
    floor = GLSLExport("// harness floor\nvec3 neumat_eval(vec3 wi, vec3 wo) { return wi + wo; }", {}, False)
    torch.testing.assert_close(slang_eval(slang_from_glsl(floor, "floor"), q), q.wi + q.wo)


def test_glsl_ggx_refuses_other_materials():
    with pytest.raises(InputError, match="conductor"):
        ggx_glsl(open_material("ggx:roughness=0.2,fresnel=schlick"))
