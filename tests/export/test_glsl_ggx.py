"""The GLSL GGX of the shader speed table (`neumat.testing.glsl_ggx`) computes what the torch GGX computes."""
import pytest
import torch

from neumat.catalog.open_material import open_material
from neumat.core.errors import InputError
from neumat.core.query import Query
from neumat.testing.glsl_ggx import ggx_glsl
from neumat.testing.parity import glsl_eval, opengl_available
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


def test_glsl_ggx_refuses_other_materials():
    with pytest.raises(InputError, match="conductor"):
        ggx_glsl(open_material("ggx:roughness=0.2,fresnel=schlick"))
