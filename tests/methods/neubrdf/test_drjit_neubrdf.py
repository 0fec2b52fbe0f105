"""Parity of NeuBRDF's Dr.Jit runtime (`neumat.export.drjit`) with the torch runtime form on random queries: fp32
compute within 1e-4 relative (lookups within 1e-5 rad of a HEALPix pixel boundary left out: Dr.Jit's and torch's
float32 atan2 differ by an ulp in most lanes, which moves about 1 direction in 10^5 to the neighbouring pixel), fp16
compute within 1e-2; for every feature storage, direction inputs, pruned grids and the export files."""
from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from neumat.core.errors import InputError
from neumat.core.query import Query
from neumat.methods.neubrdf.model import NeuBRDF
from neumat.nn import healpix as hpx

pytestmark = pytest.mark.mitsuba  # Dr.Jit's LLVM backend needs the LLVM that neumat.core.llvm finds

SMALL = {"nside": 8, "feature_dim": 8, "index_bits": 5, "hidden": 16}


@pytest.fixture(scope="module")
def drjit_llvm():
    from mitsuba_util import mitsuba_or_skip
    mitsuba_or_skip()  # chooses an LLVM >= 16 before Dr.Jit loads one, or skips with the reason
    import drjit as dr
    return dr


def _directions(n: int, g: torch.Generator) -> torch.Tensor:
    w = torch.nn.functional.normalize(torch.randn(n, 3, generator=g), dim=-1)
    w[:, 2] = w[:, 2].abs()
    return w


def _near_boundary(nside: int, w: torch.Tensor, g: torch.Generator, eps: float = 1e-5) -> torch.Tensor:
    pix = hpx.vec2pix(nside, w)
    near = torch.zeros(len(w), dtype=torch.bool)
    for _ in range(8):
        moved = torch.nn.functional.normalize(w.double() + eps * torch.randn(w.shape, generator=g, dtype=torch.float64),
                                              dim=-1)
        near |= hpx.vec2pix(nside, moved.float()) != pix
    return near


def _array3(w: torch.Tensor):
    from drjit.llvm.ad import Array3f, Float
    return Array3f(*(Float(c.contiguous().numpy()) for c in w.T))


def _model(seed: int = 0, **overrides) -> NeuBRDF:
    torch.manual_seed(seed)
    model = NeuBRDF(**{**SMALL, "direction_inputs": "hd_warp", **overrides})
    with torch.no_grad():
        model.mlp.linears()[-1].weight.mul_(0.3)  # values of a BRDF's range, not exp of a random net's
    return model.train(False)


def _parity(model: NeuBRDF, compute: str = "fp32", n: int = 20000, source=None, mlp_form=None) -> float:
    """Largest relative difference of the runtime from the torch runtime form, boundary lookups left out."""
    from neumat.export.drjit.format import export_drjit
    from neumat.export.drjit.runtime import load_runtime

    if not model.is_runtime:
        model.runtime()
    g = torch.Generator().manual_seed(1)
    wi, wo = _directions(n, g), _directions(n, g)
    runtime = load_runtime(source or export_drjit(model).source(), "llvm", compute, mlp_form)
    got = torch.from_numpy(np.array(runtime.eval(_array3(wi), _array3(wo)), dtype=np.float64).T.copy())
    with torch.no_grad():
        ref = model.eval(Query(wi, wo)).double()
    keep = ~(_near_boundary(model.cfg.nside, wi, g) | _near_boundary(model.cfg.nside, wo, g))
    assert int(keep.sum()) > 0.9 * n
    return float(((got - ref).abs() / ref.abs().clamp(min=1e-30))[keep].max())


@pytest.mark.parametrize("overrides", [{}, {"direction_inputs": "none"}, {"direction_inputs": "hd"},
                                       {"features": "dense"}, {"features": "lowbit"}, {"activation": "relu"},
                                       {"nside": 64, "feature_dim": 16, "index_bits": 9, "hidden": 64}],
                         ids=["vq hd_warp", "no direction inputs", "hd", "dense", "lowbit", "relu", "paper size"])
def test_runtime_matches_the_torch_runtime_form(drjit_llvm, overrides):
    assert _parity(_model(**overrides)) < 1e-4


def test_both_mlp_forms(drjit_llvm):
    """LLVM's default constant-weight fma chains and CUDA's drjit.nn cooperative vectors, both in fp32."""
    model = _model(6)
    assert _parity(model, mlp_form="literal") < 1e-4
    assert _parity(model, mlp_form="coopvec") < 1e-4
    from neumat.export.drjit.runtime import load_runtime
    assert load_runtime(_export(model), "llvm").mlp.form == "literal"  # the LLVM default
    with pytest.raises(InputError, match="literal for fp32 only"):
        load_runtime(_export(model), "llvm", "fp16", "literal")


def _export(model):
    from neumat.export.drjit.format import export_drjit
    return export_drjit(model).source()


def test_pruned_grid_and_fp16_compute(drjit_llvm):
    g = torch.Generator().manual_seed(5)
    model = _model(3)
    model.prune(_directions(60, g), _directions(60, g))  # most pixels read ancestor corners
    assert model.pruned
    assert _parity(model) < 1e-4
    assert _parity(model, "fp16") < 1e-2  # the fp16 bound (CUDA's default compute); measured 6e-3 on paper_white


def test_a_training_form_model_is_translated_as_its_runtime_form(drjit_llvm):
    from neumat.export.drjit.format import export_drjit
    from neumat.export.drjit.runtime import load_runtime

    model = _model(4)
    exported = export_drjit(model)  # a runtime copy: the model itself stays as it was
    assert not model.is_runtime
    assert _parity(model, source=exported.source()) < 1e-4  # _parity makes `model` its runtime form
    load_runtime(exported.source(), "llvm")


def test_export_files_round_trip_and_refusals(drjit_llvm, tmp_path):
    from neumat.export.drjit.format import export_drjit
    from neumat.export.registry import load_formats

    model = _model(2).runtime()
    fmt = load_formats().get("drjit")
    written, summary = fmt.write(fmt.export(model, "fp16"), tmp_path)
    assert written == tmp_path / "drjit" and "healpix-mlp" in summary
    manifest = json.loads((written / "manifest.json").read_text())
    assert manifest["format"] == "neumat-drjit" and manifest["model"] == "neubrdf"
    with np.load(written / "arrays.npz") as arrays:
        assert arrays["first_weight"].dtype == np.float16  # the runtime form's fp16 weights, stored losslessly
    assert _parity(model, source=written) < 1e-4
    assert _parity(model, source=written / "manifest.json") < 1e-4
    # a neural texture and idw corner weights translate to "healpix-grid-mlp" (test_drjit_neubrdf_grid.py)
    assert export_drjit(NeuBRDF(**SMALL, texture_height=4, texture_width=4,
                                texture_channels=2)).manifest["program"] == "healpix-grid-mlp"
    assert export_drjit(NeuBRDF(**SMALL, runtime_interpolation="idw")).manifest["program"] == "healpix-grid-mlp"
    with pytest.raises(InputError, match="activation 'gelu' has no Dr.Jit form"):
        export_drjit(NeuBRDF(**SMALL, activation="gelu"))
    from neumat.reflectance.analytic import GGX
    with pytest.raises(InputError, match="no Dr.Jit runtime"):
        export_drjit(GGX(0.3))
    (written / "manifest.json").write_text(json.dumps({**manifest, "format_version": 99}))
    from neumat.core.errors import DataFormatError
    from neumat.export.drjit.runtime import read_export
    with pytest.raises(DataFormatError, match="format version"):
        read_export(written)
