"""Parity of the Dr.Jit runtime program "sparse-btf" (`neumat.export.drjit.sparse_btf`) with `SparseBTF.eval`
(angular "coefficient" and "value" interpolation), fp32 compute, on random queries (directions on the whole sphere, uv
well outside [0, 1]: wrap-around) and at bins and texel centres (the table's entries). As for the GLSL export
(test_glsl_sparse_btf.py): queries whose k-th and (k+1)-th nearest bins are within 1e-5 in dot product are left
out (a tie either implementation may break its own way: k-nearest interpolation jumps there), and the relative
error is taken against max(|f|, 1e-3) (f = exp(.) - eps clamps to 0 in the darkest texels)."""
from __future__ import annotations

import warnings

import numpy as np
import pytest
import torch

from btf_util import N_DIRS, SIZE, synthetic_btf, unambiguous
from neumat.core.query import Query
from neumat.methods.sparse_btf.dictionary_train import train_dictionary
from neumat.methods.sparse_btf.model import SparseBTF

pytestmark = pytest.mark.mitsuba  # Dr.Jit's LLVM backend needs the LLVM that neumat.core.llvm finds


@pytest.fixture(scope="module")
def dictionary():
    from mitsuba_util import mitsuba_or_skip
    mitsuba_or_skip()
    with warnings.catch_warnings():  # a deliberately tiny training set (test_glsl_sparse_btf.py's)
        warnings.simplefilter("ignore", UserWarning)
        return train_dictionary([synthetic_btf(s) for s in (1, 2, 3)], num_dictionaries=2, tau_train=(24, 8, 8),
                                patch=4, max_iters=4, seed=0)


def _btf(seed: int):
    btf = synthetic_btf(seed)  # made non-reciprocal: light and view bins play different roles
    btf.data = btf.data * (1 + 0.5 * btf.light_dirs[:, 0] + 0.3 * btf.light_dirs[:, 1])[:, None, None, None, None]
    return btf


def _queries(n: int, seed: int) -> Query:
    g = torch.Generator().manual_seed(seed)
    wi = torch.nn.functional.normalize(torch.randn(n, 3, generator=g) + torch.tensor([0, 0, 0.8]), dim=-1)
    wo = torch.nn.functional.normalize(torch.randn(n, 3, generator=g) + torch.tensor([0, 0, 0.8]), dim=-1)
    return Query(wi, wo, uv=torch.rand(n, 2, generator=g) * 4 - 1.5)


def _runtime_eval(model: SparseBTF, q: Query, source=None) -> torch.Tensor:
    from drjit.llvm.ad import Array3f, Float
    from neumat.export.drjit.format import export_drjit
    from neumat.export.drjit.runtime import load_runtime
    rt = load_runtime(source or export_drjit(model).source(), "llvm")
    assert rt.spatially_varying and not rt.can_sample
    f = lambda x: Float(x.contiguous().float().numpy())  # noqa: E731
    a3 = lambda w: Array3f(*(f(c) for c in w.T))  # noqa: E731
    out = rt.eval(a3(q.wi), a3(q.wo), True, (f(q.uv[:, 0]), f(q.uv[:, 1])))
    return torch.from_numpy(np.array(out, dtype=np.float64).T.copy())


def _max_error(model: SparseBTF, q: Query, source=None) -> float:
    got = _runtime_eval(model, q, source)
    with torch.no_grad():
        ref = model.eval(q).double()
    keep = unambiguous(model, q)
    assert float(keep.float().mean()) > 0.95
    below = (q.wi[:, 2] <= 0) | (q.wo[:, 2] <= 0)
    assert bool(below.any()) and bool((got[below] == 0).all())
    return float(((got - ref).abs()[keep] / ref.abs()[keep].clamp(min=1e-3)).max())


@pytest.mark.parametrize("angular", ["coefficient", "value"])
@pytest.mark.parametrize("threshold", [0.0, 0.05], ids=["fixed counts", "variable counts"])
def test_runtime_matches_torch(dictionary, threshold, angular):
    model = SparseBTF.encode(_btf(10), dictionary, (40, 10, 10), error_threshold=threshold,
                             angular=angular).train(False)
    if threshold:
        assert model.counts.min() < model.counts.max()  # the error threshold stopped some data points early
    q = _queries(3000, 0)
    err = _max_error(model, q)
    print(f"max relative error {err:.2e}", end=" ")
    assert err < 1e-4
    other = SparseBTF.encode(_btf(10), dictionary, (40, 10, 10), error_threshold=threshold,
                             angular="value" if angular == "coefficient" else "coefficient").train(False)
    with torch.no_grad():  # the two modes differ well beyond the tolerance: parity tells which one ran
        a, b = model.eval(q).double(), other.eval(q).double()
    assert float(((a - b).abs() / a.abs().clamp(min=1e-3)).max()) > 1e-2


@pytest.mark.parametrize("angular", ["coefficient", "value"])
def test_runtime_returns_table_entries_at_bins_and_texel_centres(dictionary, angular):
    model = SparseBTF.encode(_btf(12), dictionary, (40, 10, 10), angular=angular)
    g = torch.Generator().manual_seed(4)
    n = 300
    li, vi = torch.randint(0, N_DIRS, (2, n), generator=g)
    rows, cols = torch.randint(0, SIZE, (2, n), generator=g)
    uv = torch.stack([(cols + 0.5) / SIZE, 1 - (rows + 0.5) / SIZE], -1)
    q = Query(model.light_dirs[li], model.view_dirs[vi], uv=uv)
    table = model.decode().data[li, vi, rows, cols].double()
    assert torch.allclose(_runtime_eval(model, q), table, rtol=1e-4, atol=1e-6)


@pytest.mark.parametrize("angular", ["coefficient", "value"])
def test_export_files_round_trip_and_refusal(dictionary, angular, tmp_path):
    from neumat.core.errors import InputError
    from neumat.export.drjit.format import drjit_models, export_drjit
    assert "sparse-btf" in drjit_models()
    model = SparseBTF.encode(_btf(13), dictionary, (40, 10, 10), angular=angular)
    folder = export_drjit(model, "fp32").write(tmp_path / "drjit")
    assert _max_error(model, _queries(1000, 1), source=folder) < 1e-4

    class OwnEval(SparseBTF):
        def _eval_batch(self, q):
            return super()._eval_batch(q)

    with pytest.raises(InputError, match="expected a SparseBTF"):
        export_drjit(OwnEval(model.cfg))


@pytest.mark.parametrize("angular", ["coefficient", "value"])
def test_the_mitsuba_plugin_renders_a_sparse_btf_file_natively(dictionary, angular, tmp_path):
    """The .nmat through the native plugin (`neumat.integrations.mitsuba_native`): eval (f cos) at si.uv against the
    torch model, and a tiny render with the bridge's image up to float error (cosine sampling in both)."""
    import drjit as dr
    from mitsuba_util import mi_vector, to_torch
    from neumat.catalog.modelfile import save_model
    from neumat.integrations import mitsuba as plugin
    mi = plugin.register()
    model = SparseBTF.encode(_btf(14), dictionary, (40, 10, 10), angular=angular).train(False)
    path = save_model(model, tmp_path / "sbtf.nmat")
    bsdf = mi.load_dict({"type": "neumat", "filename": str(path)})
    assert "NeumatNativeBSDF" in str(bsdf) and bsdf.runtime.manifest["program"] == "sparse-btf"
    q = _queries(2000, 2)
    keep = unambiguous(model, q) & (q.wi[:, 2] > 0) & (q.wo[:, 2] > 0)
    si = dr.zeros(mi.SurfaceInteraction3f, len(q))
    si.wi = mi_vector(mi, q.wi)
    si.uv = mi.Point2f(mi.Float(q.uv[:, 0].contiguous()), mi.Float(q.uv[:, 1].contiguous()))
    ours = to_torch(bsdf.eval(mi.BSDFContext(), si, mi_vector(mi, q.wo)))
    with torch.no_grad():
        ref = model.eval(q).double() * q.wo[:, 2:3].clamp(min=0).double()
    assert float(((ours - ref).abs()[keep] / ref.abs()[keep].clamp(min=1e-3)).max()) < 1e-4

    def scene(bsdf_dict):
        return mi.load_dict({
            "type": "scene", "integrator": {"type": "path", "max_depth": 3},
            "sensor": {"type": "perspective", "fov": 30, "to_world": mi.ScalarTransform4f().look_at(
                origin=[0, 1.5, 3.5], target=[0, 0, 0], up=[0, 1, 0]),
                "film": {"type": "hdrfilm", "width": 24, "height": 24, "rfilter": {"type": "box"}},
                "sampler": {"type": "independent", "sample_count": 8}},
            "sphere": {"type": "sphere", "bsdf": bsdf_dict},
            "sun": {"type": "directional", "direction": [0.3, -1, -0.4], "irradiance": 3.0},
            "sky": {"type": "constant", "radiance": {"type": "rgb", "value": [0.6, 0.7, 0.9]}}})
    ours = torch.from_numpy(np.array(mi.render(scene({"type": "neumat", "filename": str(path)})), dtype=np.float32))
    theirs = plugin.render(scene({"type": "neumat", "filename": str(path), "native": False}))
    assert bool(torch.isfinite(ours).all()) and float(ours.mean()) > 0
    close = ((ours - theirs).abs() <= 1e-3 * theirs.abs() + 1e-4).all(-1)
    print(f"close {float(close.float().mean()):.4f} ratio {float(ours.mean() / theirs.mean()):.6f}", end=" ")
    assert float(close.float().mean()) > 0.98 and abs(float(ours.mean() / theirs.mean()) - 1) < 2e-3
