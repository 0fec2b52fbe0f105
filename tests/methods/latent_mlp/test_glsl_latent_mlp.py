"""Parity of the GLSL export of the latent-pyramid MLP models (neumip, neumip-frame, neural-appearance with its
importance sampler) with the torch models (EGL / llvmpipe)."""
import pytest
import torch

from neumat.core.errors import InputError
from neumat.core.query import Query
from neumat.export.glsl import export_glsl
from neumat.models.registry import build_model
from neumat.testing.parity import glsl_eval, opengl_available

needs_gl = pytest.mark.skipif(not opengl_available(), reason="no moderngl or no headless OpenGL 3.3 context (EGL)")

CONFIGS = {
    "neumip": {"type": "neumip", "spatial_size": 16},
    "neumip-frame": {"type": "neumip-frame", "spatial_size": 16, "spatial_channels": 6},
    "neural-appearance": {"type": "neural-appearance", "spatial_size": 16},
}


def _model(spec: dict):
    torch.manual_seed(1)
    model = build_model(spec).train(False)
    with torch.no_grad():  # move frames, decoders and sampler away from their initial values
        for p in model.parameters():
            p.add_(0.1 * torch.randn_like(p))
    return model


def _queries(n: int, footprint: bool) -> Query:
    g = torch.Generator().manual_seed(2)

    def direction():
        w = torch.nn.functional.normalize(torch.randn(n, 3, generator=g), dim=-1)
        w[:, 2] = w[:, 2].abs().clamp(min=0.1)
        return torch.nn.functional.normalize(w, dim=-1)

    wi, wo = direction(), direction()
    uv = torch.rand(n, 2, generator=g) * 3 - 1
    if not footprint:
        return Query(wi=wi, wo=wo, uv=uv, lod=torch.rand(n, generator=g) * 5 - 1)
    a = torch.randn(n, 2, 2, generator=g) * torch.exp2(torch.rand(n, 1, 1, generator=g) * -8)
    return Query(wi=wi, wo=wo, uv=uv, footprint=a @ a.transpose(1, 2) + 1e-8 * torch.eye(2))


@needs_gl
@pytest.mark.parametrize("name", CONFIGS)
@pytest.mark.parametrize("footprint", [True, False], ids=["footprint", "lod"])
def test_glsl_eval_matches_torch(name, footprint):
    model = _model(CONFIGS[name])
    q = _queries(2048, footprint)
    with torch.no_grad():
        ref = model.eval(q)
    out = glsl_eval(export_glsl(model, "fp32"), q)
    rel = ((out - ref).abs() / ref.abs().clamp(min=1e-6)).max(-1).values
    assert float(rel.max()) < 1e-4, f"{name}: max relative error {float(rel.max()):.2e}"


@needs_gl
def test_glsl_sampler_matches_torch():
    model = _model(CONFIGS["neural-appearance"])
    q = _queries(4096, True)
    export = export_glsl(model, "fp32")
    u = torch.rand(len(q), 2, generator=torch.Generator().manual_seed(3))
    with torch.no_grad():
        s = model.sample(q, u)
        pdf = model.pdf(q)
    wo = glsl_eval(export, q, entry="sample", u=u)
    # the same float32 formulas: equal but where u falls within rounding of a lobe boundary (none measured)
    close = (wo - s.wo).abs().max(-1).values < 1e-4
    assert float(close.float().mean()) > 0.999, float(close.float().mean())
    got = glsl_eval(export, q, entry="pdf")[:, 0]
    assert float(((got - pdf).abs() / pdf.clamp(min=1e-6)).max()) < 1e-4


@needs_gl
def test_glsl_albedo_output_matches_torch():
    from neumat.testing.parity import glsl_run

    model = _model({**CONFIGS["neural-appearance"], "albedo": True})
    q = _queries(2048, True)
    with torch.no_grad():
        reference = model.albedo(q)
        brdf = model.eval(q)
    export = export_glsl(model, "fp32")
    assert "vec3 neumat_albedo(vec3 wi, vec3 wo, vec2 uv, mat2 footprint)" in export.entry
    fp = q.footprint
    inputs = {"wi": q.wi, "wo": q.wo, "uv": q.uv, "f": torch.stack([fp[:, 0, 0], fp[:, 0, 1], fp[:, 1, 1]], -1)}
    call = "colour = vec4(neumat_albedo(wi.xyz, wo.xyz, uv.xy, mat2(f.x, f.y, f.y, f.z)), 1.0);"
    got = glsl_run(export, inputs, call)
    assert float(((got[:, :3] - reference).abs() / reference.clamp(min=1e-6)).max()) < 1e-4
    assert float(((glsl_eval(export, q) - brdf).abs() / brdf.clamp(min=1e-6)).max()) < 1e-4  # eval unchanged


def test_export_lists_the_sampler_entry_points_and_refuses_what_it_cannot_export():
    export = export_glsl(_model(CONFIGS["neural-appearance"]))
    assert "float neumat_pdf(vec3 wi, vec3 wo, vec2 uv, mat2 footprint)" in export.entry
    assert "neumat_sample" not in export_glsl(_model(CONFIGS["neumip-frame"])).source
    with pytest.raises(InputError, match="cartesian"):
        export_glsl(build_model({"type": "nbrdf-uv", "spatial_size": 16}))
