"""Parity of the GLSL export of SparseBTF with `SparseBTF.eval` (coefficient-space path), on EGL / llvmpipe."""
import json

import pytest
import torch

from neumat.core.errors import InputError
from neumat.core.query import Query
from neumat.export.glsl import export_glsl
from neumat.methods.sparse_btf.model import SparseBTF
from neumat.methods.sparse_btf.dictionary_train import train_dictionary
from neumat.testing.parity import glsl_eval, opengl_available

from btf_util import N_DIRS, SIZE, non_reciprocal_btf, synthetic_btf, unambiguous

needs_gl = pytest.mark.skipif(not opengl_available(), reason="no moderngl or no headless OpenGL 3.3 context (EGL)")


@pytest.fixture(scope="module")
def dictionary():
    return train_dictionary([synthetic_btf(s) for s in (1, 2, 3)], num_dictionaries=2, tau_train=(24, 8, 8),
                            patch=4, max_iters=4, seed=0)


def _queries(n: int, seed: int) -> Query:
    """Directions on the whole sphere (some below the horizon) and uv well outside [0, 1] (wrap-around)."""
    g = torch.Generator().manual_seed(seed)
    wi = torch.nn.functional.normalize(torch.randn(n, 3, generator=g) + torch.tensor([0, 0, 0.8]), dim=-1)
    wo = torch.nn.functional.normalize(torch.randn(n, 3, generator=g) + torch.tensor([0, 0, 0.8]), dim=-1)
    return Query(wi, wo, uv=torch.rand(n, 2, generator=g) * 4 - 1.5)


def _assert_parity(model: SparseBTF, q: Query) -> None:
    ref = model.eval(q)
    out = glsl_eval(export_glsl(model), q)
    keep = unambiguous(model, q)
    assert keep.float().mean() > 0.95
    below = (q.wi[:, 2] <= 0) | (q.wo[:, 2] <= 0)
    assert below.any() and (out[below] == 0).all()
    err = (out - ref).abs()[keep] / ref.abs()[keep].clamp(min=1e-3)
    assert float(err.max()) < 1e-4, float(err.max())


@needs_gl
def test_shader_matches_eval_on_random_queries(dictionary):
    model = SparseBTF.encode(non_reciprocal_btf(10), dictionary, (40, 10, 10)).train(False)
    _assert_parity(model, _queries(2000, 0))


@needs_gl
def test_shader_matches_eval_with_variable_coefficient_counts(dictionary):
    model = SparseBTF.encode(non_reciprocal_btf(11), dictionary, (60, 12, 12), error_threshold=0.05)
    counts = model.counts.float()
    assert counts.min() < counts.max()          # the error threshold stopped some data points early
    _assert_parity(model, _queries(1500, 1))


@needs_gl
def test_shader_returns_table_entries_at_bins_and_texel_centres(dictionary, gen):
    model = SparseBTF.encode(non_reciprocal_btf(12), dictionary, (40, 10, 10))
    n = 200
    li, vi = torch.randint(0, N_DIRS, (2, n), generator=gen)
    rows, cols = torch.randint(0, SIZE, (2, n), generator=gen)
    uv = torch.stack([(cols + 0.5) / SIZE, 1 - (rows + 0.5) / SIZE], -1)
    q = Query(model.light_dirs[li], model.view_dirs[vi], uv=uv)
    table = model.decode().data[li, vi, rows, cols]
    assert torch.allclose(glsl_eval(export_glsl(model), q), table, rtol=1e-4, atol=1e-6)


def test_export_files_and_bad_input(dictionary, tmp_path):
    model = SparseBTF.encode(non_reciprocal_btf(13), dictionary, (40, 10, 10))
    exported = export_glsl(model)
    folder = exported.write(tmp_path / "sbtf")
    manifest = json.loads((folder / "manifest.json").read_text())
    assert manifest["entry"][0] == "vec3 neumat_eval(vec3 wi, vec3 wo, vec2 uv)"
    for entry in manifest["entry"]:
        assert entry.split("(")[0].split()[-1] + "(" in exported.source
    assert set(manifest["textures"]) == {"sbtf_codes", "sbtf_points", "sbtf_dict_s", "sbtf_dict_a", "sbtf_stats"}
    codes = manifest["textures"]["sbtf_codes"]
    assert (codes["layers"], codes["height"], codes["width"]) == (3, model.counts.shape[1], 40)
    assert (folder / "sbtf_codes.f32").stat().st_size == 3 * model.counts.shape[1] * 40 * 4 * 4
    model.values[0, 0, 0] = float("nan")
    with pytest.raises(InputError, match="non-finite"):
        export_glsl(model)
    odd = SparseBTF.encode(non_reciprocal_btf(13), dictionary, (40, 10, 10), neighbours=3)
    odd.cfg.neighbours = 5
    odd.view_dirs = odd.view_dirs[:4]
    odd.cfg.n_view = 4
    with pytest.raises(InputError, match="same neighbour count"):
        export_glsl(odd)
