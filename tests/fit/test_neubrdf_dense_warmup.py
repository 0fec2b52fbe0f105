"""NeuBRDF's dense warm-up (recipe option dense_warmup): dense phase, k-means switch, VQ phase, in one fit."""
from __future__ import annotations

from dataclasses import replace

import pytest
import torch

from neumat.catalog.open_material import open_material
from neumat.core.errors import InputError
from neumat.fit.recipe import recipe_config_for_source, recipe_for
from neumat.fit.trainer import fit
from neumat.models.neubrdf import NeuBRDF

SMALL = dict(nside=2, index_bits=2, hidden=4)


class Interrupt(Exception):
    pass


def _recipe(warmup: float, steps: int = 6, candidates: int = 0):
    r = recipe_for("neubrdf")
    return replace(r, steps=steps, batch_size=64, log_every=1, checkpoint_every=1, lr_decay_every=2,
                   options={**r.options, "dense_warmup": warmup, "vq_candidates": candidates})


def _run(recipe, **kw):
    torch.manual_seed(0)
    source = open_material("ggx:roughness=0.3")
    model = NeuBRDF(**{**recipe_config_for_source("neubrdf", source, recipe.options), **SMALL})
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


@pytest.mark.parametrize("stop_at, candidates", [(2, 0), (3, 0), (4, 0), (3, 2), (4, 2)])
def test_dense_warmup_resumes_bit_for_bit_either_side_of_the_switch(stop_at, candidates, tmp_path):
    """A checkpoint inside the dense phase (2), at the switch (3: written after quantisation) and inside the
    VQ phase (4) resumes to the uninterrupted fit: same state and history (also with vq_candidates)."""
    recipe = _recipe(0.5, candidates=candidates)
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
    with pytest.raises(InputError, match=r"vq_candidates: expected 0 \(all codewords\) or 1 .. 4"):
        fit(NeuBRDF(features="dense", **SMALL), source, _recipe(0.5, candidates=5), progress=False)
    assert recipe_config_for_source("neubrdf", source, {"dense_warmup": 0.0}) == {}
