"""Parity of the NeuBRDF GLSL export with the torch model (EGL / llvmpipe): the shader's HEALPix indexing
against `neumat.nn.healpix` and healpy, and `neumat_eval` against `NeuBRDF.eval` for every feature storage,
both corner weightings, pruned grids, the runtime mode, the neural texture and the paper's sizes."""
import json

import pytest
import torch

from neumat.core.errors import InputError
from neumat.core.query import Query
from neumat.export.glsl import export_glsl
from neumat.export.glsl_common import GLSL_IMAGE_VERSION, GLSL_VERSION
from neumat.methods.neubrdf.glsl import hemisphere_pixels
from neumat.methods.neubrdf.model import NeuBRDF
from neumat.models.half_precision import half_rounded
from neumat.nn import healpix as hpx
from neumat.testing.parity import glsl_eval, glsl_run, opengl_available

needs_gl = pytest.mark.skipif(not opengl_available(), reason="no moderngl or no headless OpenGL 3.3 context (EGL)")

SMALL = {"nside": 8, "feature_dim": 8, "index_bits": 5, "hidden": 16}


def _directions(n: int, g: torch.Generator, upper: bool) -> torch.Tensor:
    w = torch.nn.functional.normalize(torch.randn(n, 3, generator=g), dim=-1)
    if upper:
        w[:, 2] = w[:, 2].abs()
    return w


def _near_boundary(nside: int, w: torch.Tensor, g: torch.Generator, eps: float = 1e-5) -> torch.Tensor:
    """Mask (N,) of directions whose ring pixel changes within about eps radians (float32 rounding of the
    shader's atan / sqrt may put them in the neighbouring pixel)."""
    pix = hpx.vec2pix(nside, w)
    near = torch.zeros(len(w), dtype=torch.bool)
    for _ in range(8):
        moved = torch.nn.functional.normalize(w.double() + eps * torch.randn(w.shape, generator=g, dtype=torch.float64),
                                              dim=-1)
        near |= hpx.vec2pix(nside, moved.float()) != pix
    return near


def _export_with_nside(nside: int):
    """An export whose HEALPix functions run at `nside` (the model itself stays small)."""
    shader = export_glsl(NeuBRDF(nside=8, feature_dim=4, index_bits=2, hidden=4, hidden_layers=1).train(False),
                         "fp32")
    shader.source = shader.source.replace("const int NM_NSIDE = 8;", f"const int NM_NSIDE = {nside};")
    return shader


def _ints(shader, w: torch.Tensor, expression: str) -> torch.Tensor:
    """An ivec4 GLSL expression of `w` evaluated exactly (split in 16-bit halves: floats hold 24 bits)."""
    hi = glsl_run(shader, {"w": w}, f"ivec4 r = {expression}; colour = vec4(r / 65536);")
    lo = glsl_run(shader, {"w": w}, f"ivec4 r = {expression}; colour = vec4(r % 65536);")
    return hi.long() * 65536 + lo.long()


@needs_gl
@pytest.mark.parametrize("nside", [1, 2, 8, 64, 1024])
def test_shader_pixels_and_corners_match_healpix(nside):
    healpy = pytest.importorskip("healpy", reason="healpy gives the reference pixelisation")
    g = torch.Generator().manual_seed(nside)
    w = _directions(20000, g, upper=False)
    w[:8] = torch.tensor([[0, 0, 1.0], [0, 0, -1.0], [1.0, 0, 0], [0, 1.0, 0], [-1.0, 0, 0], [0, -1.0, 0],
                          [0.6, 0, 0.8], [0, -0.6, -0.8]])
    shader = _export_with_nside(nside)
    pix = _ints(shader, w, "ivec4(nm_vec2pix(w.xyz))")[:, 0]
    reference = torch.from_numpy(healpy.vec2pix(nside, *w.double().numpy().T))
    differ = pix != reference
    assert not (differ & ~_near_boundary(nside, w, g)).any(), f"{int(differ.sum())} pixels differ from healpy"
    assert float(differ.float().mean()) < 5e-3
    for level in range(nside.bit_length()):
        corners = _ints(shader, w, f"nm_corner_vertices(nm_vec2pix(w.xyz), {level})")
        assert torch.equal(corners, hpx.ancestor_corner_vertices(nside, pix, level)), f"level {level}"


def _model(spec: dict, seed: int = 1) -> NeuBRDF:
    torch.manual_seed(seed)
    model = NeuBRDF(**spec).train(False)
    with torch.no_grad():  # an MLP that is far from constant, so that every input matters
        for p in model.mlp.parameters():
            p.add_(0.3 * torch.randn_like(p))
        if model.texture is not None:
            for level in model.texture.levels:
                level.mul_(10.0)
    return model


def _parity(model: NeuBRDF, n: int = 4096, lod: bool = False, seed: int = 2, precision: str = "fp32",
            reference: NeuBRDF | None = None, version: str | None = None) -> float:
    """Largest relative difference of the shader (at `precision`, compiled under `version`, default its fastest)
    from `reference`.eval (default: the model) over random queries (both directions on the hemisphere, uv over
    three tiles), leaving out lookups within 1e-5 rad of a pixel boundary."""
    g = torch.Generator().manual_seed(seed)
    wi, wo = _directions(n, g, upper=True), _directions(n, g, upper=True)
    uv = torch.rand(n, 2, generator=g) * 3 - 1 if model.texture is not None else None
    q = Query(wi=wi, wo=wo, uv=uv, lod=torch.rand(n, generator=g) * 5 - 1 if lod else None)
    with torch.no_grad():
        reference = (reference or model).eval(q)
    out = glsl_eval(export_glsl(model, precision), q, version=version)
    nside = model.cfg.nside
    keep = ~(_near_boundary(nside, wi, g) | _near_boundary(nside, wo * torch.tensor([1.0, 1.0, -1.0]), g))
    assert int(keep.sum()) > 0.9 * n
    return float(((out - reference).abs() / reference.abs().clamp(min=1e-6))[keep].max())


CONFIGS = {
    "vq-idw": SMALL,
    "vq-uniform": {**SMALL, "interpolation": "uniform"},
    "dense": {**SMALL, "features": "dense"},
    "lowbit": {**SMALL, "features": "lowbit", "lowbit_bits": 3},
    "silu-3-layers": {**SMALL, "activation": "silu", "hidden_layers": 3},
    "nside-1": {**SMALL, "nside": 1},
    "direction-inputs": {**SMALL, "direction_inputs": "hd"},
    "direction-inputs-warped": {**SMALL, "direction_inputs": "hd_warp"},
}


@needs_gl
@pytest.mark.parametrize("name", CONFIGS)
def test_eval_matches_torch(name):
    error = _parity(_model(CONFIGS[name]))
    assert error < 1e-4, f"{name}: max relative difference {error:.2e}"


@needs_gl
def test_runtime_and_pruned_grids_match_torch():
    model = _model(SMALL)
    g = torch.Generator().manual_seed(5)
    model.prune(_directions(60, g, upper=True), _directions(60, g, upper=True))  # most pixels pruned
    assert int((model.level_i > 0).sum()) > 0.5 * len(model.level_i)
    assert _parity(model) < 1e-4
    model.runtime()  # frozen indices, 1/4 weights, runtime table in torch
    assert model.is_runtime
    assert _parity(model) < 1e-4


@needs_gl
@pytest.mark.parametrize("features", ["vq", "dense"])
def test_inverse_distance_runtime_matches_torch(features):
    """runtime_interpolation="idw": the shader of the runtime model reads the vertex directions and weights the
    corners as the runtime's slot table does."""
    model = _model({**SMALL, "features": features, "runtime_interpolation": "idw"})
    model.runtime()
    assert model.is_runtime and "nbrdf_vertices" in export_glsl(model).textures
    assert _parity(model) < 1e-4


@needs_gl
def test_neural_texture_matches_torch():
    model = _model({**SMALL, "texture_height": 16, "texture_width": 12, "texture_channels": 6,
                    "texture_levels": 3})
    shader = export_glsl(model)
    assert shader.spatially_varying and "vec3 neumat_eval_lod(vec3 wi, vec3 wo, vec2 uv, float lod)" in shader.entry
    assert _parity(model, lod=True) < 1e-4
    assert _parity(model, lod=False) < 1e-4  # no lod: level 0, as eval


@needs_gl
@pytest.mark.parametrize("kind", ["hd", "hd_warp"])
@pytest.mark.parametrize("interpolation", ["uniform", "idw"])
def test_direction_inputs_runtime_and_texture_match_torch(interpolation, kind):
    """direction_inputs "hd" / "hd_warp": the shader's half / difference vectors (`nm_hd`, warped under
    NM_HD_WARP) and their place after the texture channels, in the runtime form (its table plus the direction
    columns) and with a neural texture."""
    model = _model({**SMALL, "direction_inputs": kind, "runtime_interpolation": interpolation})
    model.runtime()
    assert ("#define NM_HD_WARP" in export_glsl(model).source) == (kind == "hd_warp")
    assert _parity(model) < 1e-4
    textured = _model({**SMALL, "direction_inputs": kind, "texture_height": 8, "texture_width": 8,
                       "texture_channels": 3})
    assert "nm_hd(wi, wo, hd)" in export_glsl(textured).source
    assert _parity(textured) < 1e-4


@needs_gl
def test_paper_sizes_runtime_match_torch():
    model = _model({"nside": 64})  # N_side 64, k 16, b 9, 2 x 64 hidden (paper Sec. 4)
    model.runtime()
    assert _parity(model, n=2048) < 1e-4


def test_tables_are_compact_and_written(tmp_path):
    model = _model(SMALL)
    shader = export_glsl(model, "fp32")
    slots = 2 * hpx.hemisphere_size(8)
    assert set(shader.textures) == {"nbrdf_index", "nbrdf_features", "nbrdf_vertices"}
    index = torch.from_numpy(shader.textures["nbrdf_index"]).flatten()
    assert torch.equal(index[:slots].long(), model.grid.indices().long())
    assert torch.equal(torch.from_numpy(shader.textures["nbrdf_features"]).flatten()[:32 * 8],
                       model.grid.codebook.detach().flatten())
    model.runtime()
    runtime = export_glsl(model)
    assert set(runtime.textures) == {"nbrdf_first"}  # 1/4 weights: the runtime's first-layer table only
    assert runtime.exact == ("nbrdf_first",)  # float32 at every precision (a float32 product, as in torch)
    p, h = hemisphere_pixels(8), 16
    rows = torch.from_numpy(runtime.textures["nbrdf_first"]).reshape(-1, h)  # 1024 texels: 64 rows of 16 a line
    table = model._runtime_table
    assert torch.equal(rows[:p], table[:p]) and torch.equal(rows[p:2 * p], table[12 * 64:12 * 64 + p])
    manifest = json.loads((shader.write(tmp_path) / "manifest.json").read_text())
    assert manifest["entry"] == ["vec3 neumat_eval(vec3 wi, vec3 wo)"]
    assert (tmp_path / "nbrdf_index.f32").stat().st_size == shader.textures["nbrdf_index"].nbytes
    assert shader.images == {"nbrdf_index": 0, "nbrdf_features": 1, "nbrdf_vertices": 2}
    assert manifest["fastest_glsl_version"] == GLSL_IMAGE_VERSION
    assert runtime.images == {"nbrdf_first": 0} and runtime.fastest_glsl_version() == GLSL_IMAGE_VERSION
    manifest = json.loads((runtime.write(tmp_path / "runtime") / "manifest.json").read_text())
    assert manifest["glsl_version"] == GLSL_VERSION and manifest["fastest_glsl_version"] == GLSL_IMAGE_VERSION
    assert manifest["textures"]["nbrdf_first"]["image_unit"] == 0


def test_a_version_is_a_version_line():
    g = torch.Generator().manual_seed(0)
    q = Query(wi=_directions(4, g, upper=True), wo=_directions(4, g, upper=True))
    with pytest.raises(InputError, match="#version"):
        glsl_eval(export_glsl(_model(SMALL).runtime()), q, version="420")


def test_unsupported_activation_is_refused():
    with pytest.raises(InputError, match="gelu"):
        export_glsl(NeuBRDF(**SMALL, activation="gelu"))


@needs_gl
@pytest.mark.parametrize("features", ["vq", "dense"])
@pytest.mark.parametrize("kind", ["none", "hd_warp"])
@pytest.mark.parametrize("precision", ["fp32", "fp16"])
def test_first_layer_table_matches_torch(features, kind, precision):
    """The uniform-weight shader (`nbrdf_first`: the runtime's per-pixel first-layer table, one vec4 fetch per
    4 pre-activations, the unrolled vec4 MLP): the runtime form against its torch runtime (its floats are halves
    already, so both precisions compute the same function), and the training form with uniform weights, at fp16
    against `half_rounded` (the stored values as halves, float32 arithmetic), with a hidden width that is not a
    multiple of 4 and a neural texture."""
    spec = {**SMALL, "features": features, "direction_inputs": kind}
    model = _model(spec).runtime()
    assert "nbrdf_first" in export_glsl(model, precision).textures
    for version in (GLSL_VERSION, GLSL_IMAGE_VERSION):  # the table as a sampler2DArray, then as an image
        assert _parity(model, precision=precision, version=version) < 1e-4, version
    trained = _model({**spec, "interpolation": "uniform", "hidden": 18, "texture_height": 8, "texture_width": 8,
                      "texture_channels": 5})
    shader = export_glsl(trained, precision)
    assert set(shader.textures) == {"nbrdf_first", "neumat_spatial"}
    reference = half_rounded(trained) if precision == "fp16" else trained
    assert _parity(trained, precision=precision, reference=reference) < 1e-4


@needs_gl
def test_first_layer_table_without_hidden_layers_and_pruned_matches_torch():
    """The table feeding the output layer directly (no hidden layer), and a pruned grid's ancestor features."""
    model = _model({**SMALL, "hidden_layers": 0, "interpolation": "uniform"})
    assert _parity(model) < 1e-4
    model = _model(SMALL)
    g = torch.Generator().manual_seed(5)
    model.prune(_directions(60, g, upper=True), _directions(60, g, upper=True))
    model.runtime()
    assert _parity(model) < 1e-4
