"""Parity of the Slang export of the latent-pyramid MLP models (neumip, neumip-frame, neural-appearance with its
sampler and albedo output) with the torch models, on slangpy's CPU device; the module's files; bad inputs.

Thresholds (float32 on both sides): eval, eval_lod and albedo within 5e-5 relative (torch float32 itself is
~1e-5 from a float64 evaluation at these queries: the learned frames' lift z = sqrt(1 - x^2 - y^2) amplifies
rounding near their horizon), pdf within 1e-5 relative, sampled directions within 2e-5."""
import json

import numpy as np
import pytest
import torch

from neumat.core.errors import InputError
from neumat.core.query import Query
from neumat.nn import cpu_kernels
from neumat.export.slang import (ENTRY_CODES, QUERY_FLOATS, QUERY_LAYOUT, environment_bindings, export_slang,
                                  glsl_to_slang)
from neumat.models.registry import build_model
from neumat.testing.slang_parity import SlangKernel, slang_available, slang_eval
from tests.methods.latent_mlp.test_glsl_latent_mlp import _model, _queries as glsl_queries

needs_slang = pytest.mark.skipif(not slang_available(), reason="slangpy is not installed or its CPU device "
                                                               "cannot be created (pip install slangpy)")

CONFIGS = {
    "neumip": {"type": "neumip", "spatial_size": 16},
    "neumip-frame": {"type": "neumip-frame", "spatial_size": 16, "spatial_channels": 6},
    "neural-appearance": {"type": "neural-appearance", "spatial_size": 16, "albedo": True},
}
EVAL_TOL, PDF_TOL, SAMPLE_TOL = 5e-5, 1e-5, 2e-5


def _queries(n: int, footprint: bool) -> Query:
    """The GLSL parity queries (directions at least ~0.1 above the horizon, uv over three tiles, footprints of 2^-8
    to 1 uv or lods from -1 to 4) with 1/16 of wi turned below the horizon (value 0)."""
    q = glsl_queries(n, footprint)
    q.wi[::16, 2] *= -1
    return q


def _relative(got: torch.Tensor, ref: torch.Tensor) -> float:
    return float(((got - ref).abs() / ref.abs().clamp(min=1e-6)).max())


@pytest.fixture(scope="module")
def compiled():
    """name -> (model, SlangKernel): each module compiled once."""
    out = {}

    def get(name):
        if name not in out:
            model = _model(CONFIGS[name])
            out[name] = model, SlangKernel(export_slang(model, "fp32"))
        return out[name]
    return get


@needs_slang
@pytest.mark.parametrize("name", CONFIGS)
def test_slang_eval_matches_torch(name, compiled):
    model, kernel = compiled(name)
    for footprint in (True, False):
        q = _queries(1024, footprint)
        with torch.no_grad(), cpu_kernels.switched_off():  # the torch formulas the module translates
            ref = model.eval(q)
        out = slang_eval(kernel, q)
        assert torch.equal(out[::16], torch.zeros_like(out[::16])), "below the horizon"
        rel = _relative(out, ref)
        assert rel < EVAL_TOL, f"{name} {'footprint' if footprint else 'lod'}: max relative error {rel:.2e}"


@needs_slang
def test_slang_sampler_pdf_and_albedo_match_torch(compiled):
    model, kernel = compiled("neural-appearance")
    q = _queries(2048, True)
    q.wi[::16, 2] *= -1  # the sampler's wi above the horizon
    u = torch.rand(len(q), 2, generator=torch.Generator().manual_seed(3))
    with torch.no_grad():
        s = model.sample(q, u)
        pdf = model.pdf(q)
        albedo = model.albedo(q)
    wo = slang_eval(kernel, q, "sample", u)
    # the same float32 formulas: equal but where u falls within rounding of a lobe boundary (none measured)
    assert float((wo - s.wo).abs().max()) < SAMPLE_TOL
    assert _relative(slang_eval(kernel, q, "pdf"), pdf) < PDF_TOL
    assert _relative(slang_eval(kernel, q, "albedo"), albedo) < EVAL_TOL


@needs_slang
def test_slang_kernel_refuses_an_entry_the_export_lacks(compiled):
    _, kernel = compiled("neumip-frame")
    q = _queries(4, True)
    with pytest.raises(InputError, match="pdf"):
        slang_eval(kernel, q, "pdf")
    with pytest.raises(InputError, match="u of shape"):
        compiled("neural-appearance")[1].run("sample", q)


def test_slang_module_interfaces_and_files(tmp_path):
    plain = export_slang(_model({"type": "neural-appearance", "spatial_size": 16}))
    assert plain.interfaces == ["INeumatMaterial", "INeumatSampler"]
    assert "struct NeumatMaterial : INeumatMaterial, INeumatSampler {" in plain.source
    assert "float pdf(float3 wi, float3 wo, float2 uv, float2x2 footprint)" in plain.entry_points()
    export = export_slang(_model(CONFIGS["neumip-frame"]), "fp32")
    assert export.entries == ["eval", "eval_lod"] and "neumat_sample" not in export.source
    for glsl in ("vec3", "mix(", "fract(", "texelFetch", "sampler2DArray", "mat2"):
        assert glsl not in export.source
    folder = export.write(tmp_path / "slang")
    manifest = json.loads((folder / "manifest.json").read_text())
    assert manifest["compute"]["entry"] == "neumat_batch" and manifest["struct"] == "NeumatMaterial"
    info = manifest["buffers"]["neumat_spatial"]
    data = np.fromfile(folder / info["file"], "<f4").reshape(info["layers"], info["height"], info["width"], 4)
    assert np.array_equal(data, export.buffers["neumat_spatial"]) and data.size == 4 * info["elements"]
    assert (folder / "neumat.slang").read_text() == export.source


OTHER_FAMILIES = {
    "multiscale": {"type": "multiscale", "spatial_size": 16},
    "tripleplane": {"type": "tripleplane", "spatial_size": 16},
    "multiscale (homogeneous)": {"type": "multiscale", "spatial_size": 16, "homogeneous": True},
    "neubrdf": {"type": "neubrdf", "nside": 4, "index_bits": 4, "hidden": 16},
    "neubrdf (neural texture)": {"type": "neubrdf", "nside": 4, "index_bits": 4, "hidden": 16, "texture_height": 8,
                                 "texture_width": 8, "texture_channels": 4},
    "neubrdf (direction inputs)": {"type": "neubrdf", "nside": 4, "index_bits": 4, "hidden": 16,
                                   "direction_inputs": "hd"},
    "neubrdf (warped direction inputs)": {"type": "neubrdf", "nside": 4, "index_bits": 4, "hidden": 16,
                                          "direction_inputs": "hd_warp"},
    "neubrdf (first-layer table)": {"type": "neubrdf", "nside": 4, "index_bits": 4, "hidden": 16,
                                    "interpolation": "uniform"},
}


@needs_slang
@pytest.mark.parametrize("name", OTHER_FAMILIES)
def test_slang_export_of_the_other_families_matches_torch(name):
    """The multi-scale models and NeuBRDF through the same GLSL-to-Slang rewrite: INeumatMaterial (spatially
    varying) or INeumatBRDF (homogeneous). Tolerance EVAL_TOL, but 1e-4 for the spatially varying multi-scale
    model, the bound of its GLSL parity test (its polar angular textures lose ~eps / z^2 near the horizon; measured
    here 5.7e-5, its GLSL export 1.5e-3 on these queries); measured for the others 2e-7 to 3.4e-6."""
    tol = 1e-4 if name == "multiscale" else EVAL_TOL
    model = _model(OTHER_FAMILIES[name])
    export = export_slang(model, "fp32")
    kernel = SlangKernel(export)
    if export.entries == ["eval_brdf"]:
        assert export.interfaces == ["INeumatBRDF"]
        q = _queries(1024, True)
        q = Query(wi=q.wi, wo=q.wo)
        with torch.no_grad(), cpu_kernels.switched_off():  # the torch formulas the module translates
            ref = model.eval(q)
        out = slang_eval(kernel, q)
        assert _relative(out, ref) < tol, f"{name}: max relative error {_relative(out, ref):.2e}"
        return
    assert "INeumatMaterial" in export.interfaces
    for footprint in (True, False):
        q = _queries(1024, footprint)
        with torch.no_grad(), cpu_kernels.switched_off():  # the torch formulas the module translates
            ref = model.eval(q)
        out = slang_eval(kernel, q)
        rel = _relative(out, ref)
        assert rel < tol, f"{name} {'footprint' if footprint else 'lod'}: max relative error {rel:.2e}"


@needs_slang
def test_slang_export_applies_the_multiscale_output_bound():
    model = _model(OTHER_FAMILIES["tripleplane"])
    q = _queries(1024, True)
    with torch.no_grad(), cpu_kernels.switched_off():  # a bound below most outputs: the clamp is exercised
        model.target_max.copy_(model.eval(q).median(0).values)
        ref = model.eval(q)
    out = slang_eval(SlangKernel(export_slang(model, "fp32")), q)
    assert bool((ref == model.target_max).any())
    assert _relative(out, ref) < EVAL_TOL


@needs_slang
def test_slang_export_of_sparse_btf_matches_torch():
    """SparseBTF's coefficient-space reconstruction (its GLSL export) through the same rewrite."""
    from btf_util import synthetic_btf
    from neumat.methods.sparse_btf.model import SparseBTF
    from neumat.methods.sparse_btf.dictionary_train import train_dictionary

    dictionary = train_dictionary([synthetic_btf(s) for s in (1, 2, 3)], num_dictionaries=2, tau_train=(24, 8, 8),
                                  patch=4, max_iters=4, seed=0)
    model = SparseBTF.encode(synthetic_btf(5), dictionary, tau=(24, 8, 8))
    export = export_slang(model, "fp32")
    assert export.interfaces == ["INeumatMaterial"]
    g = torch.Generator().manual_seed(6)
    wi = torch.nn.functional.normalize(torch.randn(512, 3, generator=g) + torch.tensor([0, 0, 1.2]), dim=-1)
    wo = torch.nn.functional.normalize(torch.randn(512, 3, generator=g) + torch.tensor([0, 0, 1.2]), dim=-1)
    q = Query(wi, wo, uv=torch.rand(512, 2, generator=g) * 4 - 1.5, lod=torch.zeros(512))
    with torch.no_grad():
        ref = model.eval(q)
    rel = _relative(slang_eval(export, q), ref)
    assert rel < EVAL_TOL, f"sparse-btf: max relative error {rel:.2e}"           # measured 6.2e-7


@needs_slang
@pytest.mark.parametrize("case", ["small cartesian", "paper"])
def test_slang_export_of_neupress_matches_torch(case):
    """NeuPreSS (INeumatTranslucent): S_hat, the lobe width, light sampling and its pdf, with the bounds of its
    GLSL parity test (tests/methods/neupress/test_glsl_neupress.py: the paper's Fourier arguments reach ~400 rad,
    where float32 phases lose ~1e-4). Measured (small / paper): S_hat 4.2e-7 / 3.8e-5 of its largest value, sigma
    1.9e-6 / 5.5e-5 relative, sampled directions 2.1e-6 / 5.7e-5, pdf 1.8e-5 / 6.9e-4 relative."""
    from tests.methods.neupress.test_glsl_neupress import CASES, _model as neupress_model, _queries as neupress_queries

    m = neupress_model(**CASES[case])
    x, wi, wo, u = neupress_queries()
    export = export_slang(m)
    assert export.interfaces == ["INeumatTranslucent", "INeumatTranslucentShade"]
    kernel = SlangKernel(export)
    q = Query(wi=wi, wo=wo, x=x, n=x)
    with torch.no_grad():
        f = m.eval(Query(wi=wi, wo=wo, x=x))
        sigma = m.sigma(x, wo)
        sampled, _ = m.sample_incident(q, u)
        pdf = m.incident_pdf(q)
    s_f = slang_eval(kernel, q, "translucent")
    assert float((s_f - f).abs().max()) < 2e-3 * float(f.abs().max())
    assert torch.allclose(slang_eval(kernel, q, "sigma"), sigma, rtol=1e-3)
    assert torch.allclose(slang_eval(kernel, q, "sample_incident", u), sampled, atol=2e-3)
    assert torch.allclose(slang_eval(kernel, q, "incident_pdf"), pdf, rtol=3e-3, atol=1e-6)


def test_export_slang_refuses_other_models():
    with pytest.raises(InputError, match="GGXMipmap"):
        export_slang(build_model({"type": "ggx-mipmap", "spatial_size": 8}))
    with pytest.raises(InputError, match="cartesian"):
        export_slang(build_model({"type": "nbrdf-uv", "spatial_size": 16}))
    with pytest.raises(RuntimeError, match="dFdx"):  # GLSL the rewrite does not know is refused, not passed on
        glsl_to_slang("float f(float x) { return dFdx(x); }", {})


def _shade_run(kernel: SlangKernel, entry: str, columns: dict[str, torch.Tensor], env: np.ndarray) -> np.ndarray:
    """neumat_batch's `entry` (shade, rough_dielectric_reflection) with the query columns `columns` (name of
    QUERY_LAYOUT -> (N, k) or (N,)) and the environment (H, W, 3) bound: (N, 4) float32."""
    spy, device = kernel.spy, kernel.device
    n = len(next(iter(columns.values())))
    packed = np.zeros((n, QUERY_FLOATS), np.float32)
    for key, values in columns.items():
        values = np.asarray(values, np.float32).reshape(n, -1)
        packed[:, QUERY_LAYOUT[key]:QUERY_LAYOUT[key] + values.shape[1]] = values
    bindings = environment_bindings(env)
    usage = spy.BufferUsage
    env_buffer = device.create_buffer(element_count=len(bindings["neumat_env"]), struct_size=16,
                                      usage=usage.shader_resource, data=bindings.pop("neumat_env"))
    queries = device.create_buffer(element_count=packed.size, struct_size=4, usage=usage.shader_resource,
                                   data=packed.reshape(-1))
    results = device.create_buffer(element_count=4 * n, struct_size=4, usage=usage.unordered_access)
    kernel.kernel.dispatch(thread_count=[n, 1, 1], vars={
        **kernel.buffers, **bindings, "neumat_env": env_buffer, "neumat_queries": queries, "neumat_results": results,
        "neumat_count": n, "neumat_entry": ENTRY_CODES[entry]})
    return results.to_numpy().view(np.float32).reshape(n, 4).copy()


@needs_slang
def test_slang_shade_of_neupress_is_the_torch_estimator():
    """INeumatTranslucentShade: shade() (GGX-sampled rough-dielectric reflection of the environment plus
    lobe-sampled S_hat over one Hammersley set) equals the torch computation of the same estimator that the GLSL
    shade is tested against (tests/methods/neupress/test_glsl_neupress_shade.py, same bounds), with the environment
    bound at run time; rough_dielectric_reflection() equals its formula (Walter et al. 2007; its GLSL twin equals
    Mitsuba's roughdielectric)."""
    from tests.methods.neupress.test_glsl_neupress_shade import _env, _fresnel, _g1, _model as shade_model, _reference
    from neumat.render.lights import EnvironmentMap
    from neumat.warp import sample_uniform_sphere

    model, env = shade_model(), _env()
    export = export_slang(model, "fp32")
    assert export.interfaces == ["INeumatTranslucent", "INeumatTranslucentShade"]
    assert export.runtime_buffers == ["neumat_env"]
    kernel = SlangKernel(export)
    g = torch.Generator().manual_seed(3)
    x = sample_uniform_sphere(torch.rand(48, 2, generator=g))
    n = x.clone()
    wo = sample_uniform_sphere(torch.rand(48, 2, generator=g))
    wo = torch.where(((wo * n).sum(-1) < 0)[:, None], -wo, wo)  # the visible side
    alpha, ior, samples = 0.3, 1.5, 8
    constants = {"alpha": torch.full((48,), alpha), "ior": torch.full((48,), ior), "samples": torch.full((48,), 8.0)}
    shaded = torch.from_numpy(_shade_run(kernel, "shade", {"x": x, "n": n, "wo": wo, **constants}, env)[:, :3])
    expected = _reference(model, EnvironmentMap(env), x, n, wo, alpha, ior, samples)
    rel = (shaded - expected).abs() / expected
    assert float(expected.min()) > 0
    # the GLSL bounds are 1e-4 (median) and 2% above 1e-3: llvmpipe's transcendentals are less exact than the C++
    # target's, measured here median 1.1e-7, largest 6.1e-7
    assert float(rel.median()) < 1e-6, float(rel.median())
    assert float((rel > 1e-4).float().mean()) < 0.02  # a rare texel edge / lobe sample may differ

    wi = sample_uniform_sphere(torch.rand(48, 2, generator=g))
    wi = torch.where(((wi * n).sum(-1) < 0)[:, None], -wi, wi)
    mirror = 2 * (n * wo).sum(-1, keepdim=True) * n - wo
    wi[:8] = torch.nn.functional.normalize(mirror[:8] + 0.05 * wi[:8], dim=-1)  # near the glossy peak
    ours = torch.from_numpy(_shade_run(kernel, "rough_dielectric_reflection",
                                       {"n": n, "wo": wo, "wi": wi, **constants}, env)[:, 0])
    h = torch.nn.functional.normalize(wo + wi, dim=-1)
    cos_h = (n * h).sum(-1)
    d = alpha ** 2 / (torch.pi * (cos_h ** 2 * (alpha ** 2 - 1) + 1) ** 2)
    ref = _fresnel((wo * h).sum(-1), ior) * d * _g1(wo, h, n, alpha) * _g1(wi, h, n, alpha) / (4 * (n * wo).sum(-1))
    assert float(ref.max()) > 0.1  # a glossy peak is among the pairs
    assert torch.allclose(ours, ref, rtol=1e-5, atol=1e-7), float(((ours - ref).abs() / ref.clamp(min=1e-6)).max())


def test_environment_bindings_layout_and_refusal(tmp_path):
    from tests.methods.neupress.test_glsl_neupress_shade import _model as shade_model

    export = export_slang(shade_model(), "fp32")
    manifest = json.loads((export.write(tmp_path / "slang") / "manifest.json").read_text())
    assert manifest["runtime_buffers"]["neumat_env"]["width"] == "neumat_env_width"
    assert manifest["compute"]["kinds"]["shade"] == ENTRY_CODES["shade"]
    assert "uniform int neumat_env_height;" in export.source and "neumat_env" not in manifest["buffers"]
    env = np.arange(2 * 3 * 3, dtype=np.float32).reshape(2, 3, 3)
    b = environment_bindings(env)
    assert b["neumat_env_width"] == 3 and b["neumat_env_height"] == 2
    assert np.array_equal(b["neumat_env"][4], [12.0, 13.0, 14.0, 1.0])  # row 1, column 1
    with pytest.raises(InputError, match="radiance"):
        environment_bindings(np.zeros((4, 8)))
