"""NeuBRDF's dense warm-up (recipe option dense_warmup): dense phase, k-means switch, VQ phase, in one fit."""
from __future__ import annotations

from dataclasses import replace

import pytest
import torch

from neumat.catalog.open_material import open_material
from neumat.core.errors import InputError
from neumat.fit.method import recipe_for
from neumat.fit.trainer import fit
from neumat.methods.neubrdf.model import NeuBRDF

SMALL = dict(nside=2, index_bits=2, hidden=4)
#: grid slots of a NeuBRDF at N_side 1 and 2 (2 (6 N^2 + 6 N + 1))
SLOTS = {1: 26, 2: 74}


class Interrupt(Exception):
    pass


def _recipe(warmup: float, steps: int = 6, candidates: int = 0, coarse: float = 0.0):
    r = recipe_for("neubrdf")
    return replace(r, steps=steps, batch_size=64, log_every=1, checkpoint_every=1, lr_decay_every=2,
                   options={**r.options, "dense_warmup": warmup, "vq_candidates": candidates,
                            "coarse_fraction": coarse, "coarse_nside": 1})


def _features(recipe) -> dict:
    """The features the staged options train on (the presets set them; these tests build the model themselves)."""
    o = recipe.options
    return {"features": "dense" if o["dense_warmup"] or o["coarse_fraction"] or o["direction_features"] else "vq"}


def _run(recipe, **kw):
    torch.manual_seed(0)
    source = open_material("ggx:roughness=0.3")
    model = NeuBRDF(**{**_features(recipe), **SMALL})
    return model, fit(model, source, recipe, progress=False, device="cpu", **kw)


def test_dense_warmup_trains_dense_then_the_quantised_model():
    recipe = _recipe(0.5)
    model, res = _run(recipe)
    assert model.cfg.features == "vq"
    assert [r["phase"] for r in res.history] == ["dense"] * 3 + ["vq"] * 3
    # the VQ phase trains the codebook that the switch made: it moves from the k-means start
    torch.manual_seed(0)
    start, _ = _run(replace(recipe, steps=3, options={"dense_warmup": 0.99}))  # dense 3 steps, then the switch
    assert start.cfg.features == "vq" and not torch.equal(start.grid.codebook, model.grid.codebook)
    assert all(torch.isfinite(torch.tensor(r["loss"])) for r in res.history)


def test_vq_candidates_restrict_the_quantised_model_to_its_nearest_codewords():
    model, res = _run(_recipe(0.5, candidates=2))
    grid = model.grid
    assert model.cfg.features == "vq" and grid.logits.shape == (grid.num_vertices, 2)
    assert grid.candidates.shape == (grid.num_vertices, 2)
    assert [r["phase"] for r in res.history] == ["dense"] * 3 + ["vq"] * 3
    assert all(torch.isfinite(torch.tensor(r["loss"])) for r in res.history)
    index = grid.indices()
    assert bool((grid.candidates == index.unsqueeze(-1)).any(-1).all())  # every index is one of its candidates


def test_coarse_to_fine_trains_a_coarse_grid_then_the_models_own():
    recipe = _recipe(0.7, steps=10, candidates=2, coarse=0.3)
    torch.manual_seed(0)
    source = open_material("ggx:roughness=0.3")
    model = NeuBRDF(**{**_features(recipe), **SMALL})
    rows = []  # (phase, grid slots, N_side) at every record
    res = fit(model, source, recipe, progress=False, device="cpu",
              callback=lambda r: rows.append((r["phase"], model.grid.num_vertices, model.cfg.nside)))
    # the coarse phase's last record comes after its switch back to the model's grid
    assert rows == [("coarse", SLOTS[1], 1)] * 2 + [("coarse", SLOTS[2], 2)] + [("dense", SLOTS[2], 2)] * 4 \
        + [("vq", SLOTS[2], 2)] * 3
    assert model.cfg.features == "vq" and model.grid.candidates.shape == (SLOTS[2], 2)
    assert all(torch.isfinite(torch.tensor(r["loss"])) for r in res.history)


def test_coarse_to_fine_of_a_dense_model_and_the_options_checks(tmp_path):
    recipe = _recipe(0.0, steps=4, coarse=0.5)
    torch.manual_seed(0)
    source = open_material("ggx:roughness=0.3")
    model = NeuBRDF(features="dense", **SMALL)
    res = fit(model, source, recipe, progress=False, device="cpu")
    assert [r["phase"] for r in res.history] == ["coarse"] * 2 + ["fine"] * 2
    assert model.cfg.nside == 2 and model.cfg.features == "dense"
    # the fine phase's optimiser learns at fine_lr_scale (0.25) of the schedule's rate: its state in the
    # checkpoint written after the fine phase's first step (the schedule halves every 2 steps of a phase)
    ckpt = tmp_path / "fit.ckpt"

    def stop(record):
        if record["step"] == 3:
            raise Interrupt

    torch.manual_seed(0)
    with pytest.raises(Interrupt):
        fit(NeuBRDF(features="dense", **SMALL), source, recipe, progress=False, checkpoint=ckpt, callback=stop)
    groups = torch.load(ckpt, weights_only=True)["optimizer"]["param_groups"]
    assert [g["lr_scale"] for g in groups] == [0.25] and groups[0]["lr"] == pytest.approx(recipe.lr * 0.25)
    with pytest.raises(InputError, match=r"option.fine_lr_scale: expected a value in \(0, 1\]"):
        fit(NeuBRDF(features="dense", **SMALL), source,
            replace(recipe, options={**recipe.options, "fine_lr_scale": 0}), progress=False)
    with pytest.raises(InputError, match="coarse_fraction=0.5: needs a model built with features='dense'"):
        fit(NeuBRDF(features="vq", **SMALL), source, recipe, progress=False)
    with pytest.raises(InputError, match="at most dense_warmup=0.3"):
        fit(NeuBRDF(features="dense", **SMALL), source, _recipe(0.3, coarse=0.5), progress=False)
    bad = replace(recipe, options={**recipe.options, "coarse_nside": 2})
    with pytest.raises(InputError, match="coarse_nside: expected a power of two below the model's N_side 2"):
        fit(NeuBRDF(features="dense", **SMALL), source, bad, progress=False)
    auto = replace(recipe, options={**recipe.options, "coarse_nside": 0})  # a quarter of N_side 2: 1
    torch.manual_seed(0)
    coarse_sizes = []
    fit(NeuBRDF(features="dense", **SMALL), source, auto, progress=False,
        callback=lambda r: coarse_sizes.append(r["phase"]))
    assert coarse_sizes == ["coarse"] * 2 + ["fine"] * 2
    with pytest.raises(InputError, match="vq_candidates: needs dense_warmup"):
        fit(NeuBRDF(features="dense", **SMALL), source, _recipe(0.0, coarse=0.5, candidates=2), progress=False)


@pytest.mark.parametrize("stop_at, candidates, coarse", [(2, 0, 0.0), (3, 0, 0.0), (4, 0, 0.0), (3, 2, 0.0),
                                                           (4, 2, 0.0), (1, 2, 0.3), (2, 2, 0.3), (4, 2, 0.3)])
def test_dense_warmup_resumes_bit_for_bit_either_side_of_the_switch(stop_at, candidates, coarse, tmp_path):
    """A checkpoint inside the dense phase (2), at the switch (3: written after quantisation) and inside the
    VQ phase (4) resumes to the uninterrupted fit: same state and history (also with vq_candidates, and with a
    coarse phase: 1 inside it, 2 at the switch to the model's grid)."""
    recipe = _recipe(0.5, candidates=candidates, coarse=coarse)
    ref_model, ref = _run(recipe)
    ckpt = tmp_path / "fit.ckpt"

    def stop(record):
        if record["step"] == stop_at:
            raise Interrupt

    with pytest.raises(Interrupt):
        _run(recipe, checkpoint=ckpt, callback=stop)
    model, res = _run(recipe, checkpoint=ckpt, resume=True)
    ref_state, state = ref_model.state_dict(), model.state_dict()
    assert model.cfg == ref_model.cfg
    assert ref_state.keys() == state.keys() and all(torch.equal(ref_state[k], state[k]) for k in ref_state)
    strip = lambda h: [{k: v for k, v in r.items() if k != "seconds"} for r in h]  # noqa: E731
    assert strip(res.history) == strip(ref.history)


def test_dense_warmup_needs_a_dense_model_and_a_fraction():
    source = open_material("ggx:roughness=0.3")
    with pytest.raises(InputError, match="features='dense'"):
        fit(NeuBRDF(features="vq", **SMALL), source, _recipe(0.5), progress=False)
    with pytest.raises(InputError, match="dense_warmup"):
        fit(NeuBRDF(features="dense", **SMALL), source, _recipe(1.0), progress=False)
    with pytest.raises(InputError, match="vq_candidates: needs dense_warmup"):
        fit(NeuBRDF(features="vq", **SMALL), source, _recipe(0.0, candidates=2), progress=False)
    many = NeuBRDF(features="dense", **SMALL)  # more candidates than the 2^2 codewords: all of them
    fit(many, source, _recipe(0.5, candidates=5), progress=False)
    assert many.grid.logits.shape[1] == 2 ** SMALL["index_bits"] == 4


def test_direction_features_start_the_grid_that_trains_first(tmp_path):
    """Option direction_features: the coarse grid's first 3 channels start at its slot directions (the random
    rest and the later grids are the fit's); a resumed fit is exact with it too (the checkpoint loads over it);
    without coarse or warm-up a dense model is initialised, a VQ model refused."""
    from neumat.nn import healpix as hpx
    recipe = _recipe(0.7, steps=10, candidates=2, coarse=0.3)
    recipe = replace(recipe, options={**recipe.options, "direction_features": 10.0})
    torch.manual_seed(0)
    source = open_material("ggx:roughness=0.3")
    model = NeuBRDF(**{**_features(recipe), **SMALL})
    starts = []

    def first(record):
        if not starts:
            starts.append(model.grid.features.detach().clone())

    res = fit(model, source, replace(recipe, lr=1e-12), progress=False, callback=first)
    dirs = hpx.vertex2vec(1, hpx.grid_vertex_ids(1), torch.float32)
    torch.testing.assert_close(starts[0][:, :3], 10 * dirs, rtol=0, atol=1e-5)  # lr ~ 0: still the start
    assert all(torch.isfinite(torch.tensor(r["loss"])) for r in res.history)
    ref_model, _ = _run(recipe)
    ckpt = tmp_path / "fit.ckpt"

    def stop(record):
        if record["step"] == 2:
            raise Interrupt

    with pytest.raises(Interrupt):
        _run(recipe, checkpoint=ckpt, callback=stop)
    resumed, _ = _run(recipe, checkpoint=ckpt, resume=True)
    assert all(torch.equal(a, b) for a, b in zip(ref_model.state_dict().values(), resumed.state_dict().values()))
    plain = replace(_recipe(0.0, steps=2), options={**_recipe(0.0).options, "direction_features": 1})
    dense = NeuBRDF(features="dense", **SMALL)
    fit(dense, source, replace(plain, lr=1e-12), progress=False)
    torch.testing.assert_close(dense.grid.features[:, :3], hpx.vertex2vec(2, hpx.grid_vertex_ids(2), torch.float32),
                               rtol=0, atol=1e-6)
    with pytest.raises(InputError, match="direction_features=1.0: needs a model built with features='dense'"):
        fit(NeuBRDF(features="vq", **SMALL), source, plain, progress=False)
    for bad in (True, -1.0):
        with pytest.raises(InputError, match=r"option.direction_features: expected (a number|a value >= 0)"):
            fit(NeuBRDF(features="dense", **SMALL), source,
                replace(plain, options={**plain.options, "direction_features": bad}), progress=False)
