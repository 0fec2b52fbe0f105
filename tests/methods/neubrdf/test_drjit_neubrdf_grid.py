"""Parity of the "healpix-grid-mlp" Dr.Jit program (`neumat.export.drjit.neubrdf`) with the torch runtime forms it
translates: NeuBRDF with inverse-distance corner weights (`runtime_interpolation="idw"`), NeuBRDF with a neural
texture (spatially varying, uv-mapped; uniform and idw weights, one and two texture levels), and shared-NeuBRDF
(one codebook and MLP, several materials; the selected material and a per-lane selector). fp32 compute within 1e-4
relative on random queries (lookups within 1e-5 rad of a HEALPix pixel boundary left out, as in
test_drjit_neubrdf.py), fp16 compute within 1e-2."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from neumat.core.errors import InputError
from neumat.core.query import Query
from neumat.methods.neubrdf.shared_model import MaterialQuery, SharedNeuBRDF
from tests.methods.neubrdf.test_drjit_neubrdf import (  # noqa: F401  (drjit_llvm: a fixture)
    SMALL, _array3, _directions, _model, _near_boundary, drjit_llvm)

pytestmark = pytest.mark.mitsuba  # Dr.Jit's LLVM backend needs the LLVM that neumat.core.llvm finds

TEXTURE = {"texture_height": 8, "texture_width": 6, "texture_channels": 3}


def _shared(seed: int = 0, **overrides) -> SharedNeuBRDF:
    torch.manual_seed(seed)
    model = SharedNeuBRDF(**{**SMALL, "num_materials": 3, **overrides})
    with torch.no_grad():
        model.mlp.linears()[-1].weight.mul_(0.3)
    return model.train(False)


def _parity(model, compute: str = "fp32", n: int = 20000, source=None, per_lane: bool = False) -> float:
    """Largest relative difference of the Dr.Jit runtime from the torch runtime form on random directions (and uv
    in [-1, 2), wrapping, for a textured model; random materials per lane with `per_lane`), boundary lookups left
    out."""
    from drjit.llvm.ad import Float, UInt

    from neumat.export.drjit.format import export_drjit
    from neumat.export.drjit.runtime import load_runtime

    if not model.is_runtime:
        model.runtime()
    g = torch.Generator().manual_seed(1)
    wi, wo = _directions(n, g), _directions(n, g)
    uv = torch.rand(n, 2, generator=g) * 3 - 1
    runtime = load_runtime(source or export_drjit(model).source(), "llvm", compute)
    assert runtime.manifest["program"] == "healpix-grid-mlp"
    kwargs = {}
    if getattr(model, "texture", None) is not None:
        assert runtime.spatially_varying
        kwargs["uv"] = (Float(uv[:, 0].numpy()), Float(uv[:, 1].numpy()))
    q = Query(wi, wo, uv=uv)
    if per_lane:
        ids = torch.randint(0, model.cfg.num_materials, (n,), generator=g)
        kwargs["material"] = UInt(ids.numpy().astype(np.uint32))
        q = MaterialQuery(wi, wo, material=ids)
    got = torch.from_numpy(np.array(runtime.eval(_array3(wi), _array3(wo), **kwargs), dtype=np.float64).T.copy())
    with torch.no_grad():
        ref = model.eval(q).double()
    keep = ~(_near_boundary(model.cfg.nside, wi, g) | _near_boundary(model.cfg.nside, wo, g))
    assert int(keep.sum()) > 0.9 * n and float(ref[keep].min()) > 0
    return float(((got - ref).abs() / ref.abs().clamp(min=1e-30))[keep].max())


@pytest.mark.parametrize("overrides", [{}, {"direction_inputs": "none"}, {"features": "dense"}, {"features": "lowbit"},
                                       {"activation": "relu"}, {"activation": "silu"},
                                       {"nside": 64, "feature_dim": 16, "index_bits": 9, "hidden": 64}],
                         ids=["vq hd_warp", "no direction inputs", "dense", "lowbit", "relu", "silu", "paper size"])
def test_idw_corner_weights_match_the_torch_runtime_form(drjit_llvm, overrides):
    assert _parity(_model(**{"runtime_interpolation": "idw", **overrides})) < 1e-4


def test_idw_pruned_grid_and_fp16_compute(drjit_llvm):
    g = torch.Generator().manual_seed(5)
    model = _model(3, runtime_interpolation="idw")
    model.prune(_directions(60, g), _directions(60, g))  # most pixels read ancestor corners
    assert model.pruned
    assert _parity(model) < 1e-4
    assert _parity(model, "fp16") < 1e-2


@pytest.mark.parametrize("overrides", [{}, {"runtime_interpolation": "idw"}, {"texture_levels": 2},
                                       {"runtime_interpolation": "idw", "direction_inputs": "none",
                                        "features": "dense"}],
                         ids=["uniform", "idw", "two levels", "idw dense no direction inputs"])
def test_a_neural_texture_matches_the_torch_runtime_form(drjit_llvm, overrides):
    """T(uv) bilinear at the finest level, wrapping (the torch form without a lod, what the bridge evaluates)."""
    assert _parity(_model(7, **TEXTURE, **overrides)) < 1e-4


@pytest.mark.parametrize("overrides", [{}, {"interpolation": "uniform"}, {"direction_inputs": "hd"},
                                       {"features": "dense"}],
                         ids=["idw (its default)", "uniform", "hd", "dense"])
def test_shared_neubrdf_matches_the_torch_runtime_form(drjit_llvm, overrides):
    model = _shared(**overrides)
    assert _parity(model, per_lane=True) < 1e-4  # a material per lane
    model.select(2)
    assert _parity(model) < 1e-4  # the selected material, the manifest's default


def test_shared_neubrdf_pruned_and_selected_from_a_training_form_model(drjit_llvm):
    from neumat.export.drjit.format import export_drjit
    from neumat.export.drjit.runtime import load_runtime

    g = torch.Generator().manual_seed(4)
    model = _shared(5)
    model.prune(1, _directions(60, g), _directions(60, g))
    model.select(1)
    exported = export_drjit(model)  # a runtime copy: the model itself stays as it was
    assert not model.is_runtime and exported.manifest["material"] == 1 and exported.manifest["pruned"]
    assert _parity(model, source=exported.source()) < 1e-4
    assert _parity(model, source=exported.source(), per_lane=True) < 1e-4
    assert _parity(model, "fp16", source=exported.source()) < 1e-2
    runtime = load_runtime(exported.source(), "llvm")
    assert runtime.select(0).material == 0
    with pytest.raises(InputError, match="material index"):
        runtime.select(3)


def test_export_files_round_trip_and_what_is_still_refused(drjit_llvm, tmp_path):
    from neumat.export.drjit.format import export_drjit
    from neumat.export.registry import load_formats

    fmt = load_formats().get("drjit")
    for model in (_model(2, runtime_interpolation="idw", **TEXTURE), _shared(2)):
        model.runtime()
        written, summary = fmt.write(fmt.export(model, "fp16"), tmp_path / model.name)
        assert "healpix-grid-mlp" in summary
        with np.load(written / "arrays.npz") as arrays:
            assert arrays["first_weight"].dtype == np.float16  # the runtime form's fp16 weights, stored losslessly
            assert arrays["vertex_dirs"].dtype == np.float32
        assert _parity(model, source=written) < 1e-4
    # the uniform, untextured NeuBRDF keeps its "healpix-mlp" program
    assert export_drjit(_model(1)).manifest["program"] == "healpix-mlp"
    with pytest.raises(InputError, match="activation 'gelu' has no Dr.Jit form"):
        export_drjit(_model(1, activation="gelu", runtime_interpolation="idw"))
    with pytest.raises(InputError, match="activation 'gelu' has no Dr.Jit form"):
        export_drjit(_shared(1, activation="gelu"))
