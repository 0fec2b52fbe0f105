"""NeuPreSS GLSL export: appearance, lobe width, light sampling and its density on headless OpenGL against
the torch model."""
import pytest
import torch

from neumat import InputError
from neumat.core.query import Query
from neumat.export.glsl import export_glsl
from neumat.methods.neupress.glsl import export_neupress
from neumat.methods.neupress.model import NeuPreSS
from neumat.testing.parity import glsl_eval, glsl_run, opengl_available
from neumat.warp import sample_uniform_sphere

needs_gl = pytest.mark.skipif(not opengl_available(), reason="no moderngl or no headless OpenGL 3.3 context (EGL)")


def _model(**kw):
    torch.manual_seed(0)
    m = NeuPreSS(**kw)
    m.set_bounds(torch.tensor([-1.0, -1.2, -0.9]), torch.tensor([1.1, 1.0, 1.0]))
    with torch.no_grad():  # make the sampler's output vary over its clamp range
        m.sampler[-1].weight.mul_(30.0)
    return m


def _queries(n=300):
    g = torch.Generator().manual_seed(3)
    x = sample_uniform_sphere(torch.rand(n, 2, generator=g))
    wi, wo = (sample_uniform_sphere(torch.rand(n, 2, generator=g)) for _ in range(2))
    return x, wi, wo, torch.rand(n, 2, generator=g)


CASES = {
    # first layer, one skip pair, one plain layer; odd feature count pads the arrays
    "small cartesian": dict(features=7, width=12, layers=4, sampler_hidden=(10, 6), feature_mean=0.0,
                            feature_std=0.3, direction_encoding="cartesian"),
    # the same without skip connections (the paper's Fig. 7 ablation)
    "no skips": dict(features=7, width=12, layers=5, sampler_hidden=(10, 6), feature_mean=0.0,
                     feature_std=0.3, skips=False),
    # the paper's sizes and Fourier scale (arguments up to ~400 rad)
    "paper": dict(feature_mean=18.0, feature_std=1.0),
}


@needs_gl
@pytest.mark.parametrize("case", CASES)
def test_shader_matches_the_model(case):
    m = _model(**CASES[case])
    x, wi, wo, u = _queries()
    export = export_neupress(m)
    inputs = {"wi": wi, "x": x, "wo": wo, "n": x, "u": u}
    with torch.no_grad():
        f = m.eval(Query(wi=wi, wo=wo, x=x))
        sigma = m.sigma(x, wo)
        sampled, _ = m.sample_incident(Query(wi=wi, wo=wo, x=x, n=x), u)
        pdf = m.incident_pdf(Query(wi=wi, wo=wo, x=x, n=x))
    g_f = glsl_run(export, inputs, "colour = vec4(neumat_translucent(wi.xyz, x.xyz, wo.xyz), 1.0);")[:, :3]
    g_sigma = glsl_run(export, inputs, "colour = vec4(neumat_sigma(x.xyz, wo.xyz));")[:, 0]
    g_wi = glsl_run(export, inputs, "colour = vec4(neumat_sample_incident(x.xyz, wo.xyz, n.xyz, u.xy), 1.0);")[:, :3]
    g_pdf = glsl_run(export, inputs, "colour = vec4(neumat_incident_pdf(wi.xyz, x.xyz, wo.xyz, n.xyz));")[:, 0]
    scale = float(f.abs().max())
    assert float((g_f - f).abs().max()) < 2e-3 * scale, float((g_f - f).abs().max()) / scale
    assert float(sigma.max() / sigma.min()) > 2  # the lobe width varies over the queries
    assert torch.allclose(g_sigma, sigma, rtol=1e-3)
    assert torch.allclose(g_wi, sampled, atol=2e-3)
    assert torch.allclose(g_pdf, pdf, rtol=3e-3, atol=1e-6)


@needs_gl
def test_glsl_eval_of_a_neupress_export_is_s_hat_at_the_query_position():
    """The generic evaluator (the export-parity suite's) calls neumat_translucent at q.x; without x, one error."""
    m = _model(**CASES["small cartesian"])
    x, wi, wo, _ = _queries(64)
    export = export_neupress(m)
    with torch.no_grad():
        f = m.eval(Query(wi=wi, wo=wo, x=x))
    got = glsl_eval(export, Query(wi=wi, wo=wo, x=x))
    assert float((got - f).abs().max()) < 2e-3 * float(f.abs().max())
    with pytest.raises(InputError, match="needs Query.x"):
        glsl_eval(export, Query(wi=wi, wo=wo))


def test_export_glsl_dispatches_and_rejects_bad_models(tmp_path):
    m = _model(**CASES["small cartesian"])
    export = export_glsl(m)
    folder = export.write(tmp_path / "shader")
    assert (folder / "neumat_weights.f32").stat().st_size == export.textures["neumat_weights"].nbytes
    assert "neumat_translucent" in (folder / "neumat.glsl").read_text()
    with pytest.raises(InputError, match="NeuPreSS"):
        export_neupress(object())
    with torch.no_grad():
        m.appearance.out.bias.fill_(float("nan"))
    with pytest.raises(InputError, match="non-finite"):
        export_neupress(m)
