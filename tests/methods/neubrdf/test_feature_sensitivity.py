"""neumat.methods.neubrdf.feature_sensitivity against central differences of the fit's loss (float64), and recipe option
kmeans_weights: a fit with the sensitivity-weighted k-means ends the warm-up on other codewords than plain k-means,
and bad values are refused."""
from __future__ import annotations

from dataclasses import replace

import pytest
import torch

from neumat.catalog.open_material import open_material
from neumat.core.errors import InputError
from neumat.core.query import Query
from neumat.methods.neubrdf.feature_sensitivity import feature_sensitivity
from neumat.fit.phase import FitContext, loss_module, online_targets, query_draw
from neumat.fit.method import recipe_for
from neumat.fit.trainer import fit
from neumat.methods.neubrdf.model import NeuBRDF


def _context(model, source, loss):
    recipe = replace(recipe_for("neubrdf"), batch_size=256)
    return FitContext(model=model, source=source, recipe=recipe, device=torch.device("cpu"),
                      generator=torch.Generator().manual_seed(0), loss=loss)


@pytest.mark.parametrize("loss", ["l2", "log_cos"])
def test_sensitivity_is_the_squared_loss_gradient_by_central_differences(loss):
    torch.manual_seed(0)
    source = open_material("ggx:roughness=0.3")
    model = NeuBRDF(nside=2, feature_dim=4, index_bits=2, hidden=8, features="dense").double()
    ctx = _context(model, source, loss)
    sens = feature_sensitivity(ctx, batches=1, seed=5)
    assert sens.shape == model.grid.features.shape and model.grid.features.grad is None
    # the same batch, drawn again: d loss / d F[s, j] by central differences at the most sensitive entries
    q = query_draw(ctx)(256, torch.Generator().manual_seed(5), torch.device("cpu"))
    target = online_targets(ctx, q).double()
    q = Query(q.wi.double(), q.wo.double())  # the model then answers in float64 (the sensitivity's own: float32)
    loss_fn = loss_module(ctx)
    feats = model.grid.features
    checked = 0
    for flat in sens.flatten().topk(6).indices.tolist():
        s, j = divmod(flat, feats.shape[1])
        h = 1e-6
        with torch.no_grad():
            feats[s, j] += h
            up = float(loss_fn(model.eval(q), target, q))
            feats[s, j] -= 2 * h
            down = float(loss_fn(model.eval(q), target, q))
            feats[s, j] += h
        fd = (up - down) / (2 * h)
        assert fd ** 2 == pytest.approx(float(sens[s, j]), rel=1e-4)
        checked += 1
    assert checked == 6 and float(sens.max()) > 0
    # more batches add up: two batches are at least the first one
    assert bool((feature_sensitivity(ctx, batches=2, seed=5) >= sens - 1e-18).all())
    with torch.no_grad():  # as from a phase hook that runs without gradients: the same numbers
        torch.testing.assert_close(feature_sensitivity(ctx, batches=1, seed=5), sens, rtol=0, atol=0)


def test_sensitivity_needs_a_dense_grid_and_a_batch_count():
    source = open_material("ggx:roughness=0.3")
    with pytest.raises(InputError, match="dense feature grid"):
        feature_sensitivity(_context(NeuBRDF(nside=2, index_bits=2, hidden=4), source, "l2"), 1, 0)
    with pytest.raises(InputError, match="batches must be an integer >= 1"):
        feature_sensitivity(_context(NeuBRDF(nside=2, hidden=4, features="dense"), source, "l2"), 0, 0)


def _fit(weights: str):
    r = recipe_for("neubrdf")
    recipe = replace(r, steps=6, batch_size=64, lr_decay_every=2, log_every=1,
                     options={**r.options, "dense_warmup": 0.5, "vq_candidates": 2, "kmeans_weights": weights})
    torch.manual_seed(0)
    source = open_material("ggx:roughness=0.3")
    model = NeuBRDF(**{"features": "dense", "nside": 2, "index_bits": 2,
                       "hidden": 4})
    res = fit(model, source, recipe, progress=False, device="cpu")
    return model, res


def test_kmeans_weights_sensitivity_changes_the_codebook_the_warmup_ends_with():
    plain, _ = _fit("uniform")
    weighted, res = _fit("sensitivity")
    assert weighted.cfg.features == "vq" and [r["phase"] for r in res.history] == ["dense"] * 3 + ["vq"] * 3
    assert all(torch.isfinite(torch.tensor(r["loss"])) for r in res.history)
    assert not torch.equal(plain.grid.codebook, weighted.grid.codebook)


def test_kmeans_weights_refuses_unknown_values_and_fits_without_a_warmup():
    source = open_material("ggx:roughness=0.3")
    r = recipe_for("neubrdf")
    bad = replace(r, steps=4, batch_size=64, options={**r.options, "dense_warmup": 0.5, "kmeans_weights": "fisher"})
    with pytest.raises(InputError, match="option.kmeans_weights: expected one of 'uniform', 'sensitivity', "
                                         "got 'fisher'"):
        fit(NeuBRDF(nside=2, hidden=4, features="dense"), source, bad, progress=False)
    no_warmup = replace(bad, options={**r.options, "kmeans_weights": "sensitivity"})
    with pytest.raises(InputError, match="needs dense_warmup > 0"):
        fit(NeuBRDF(nside=2, hidden=4, features="dense"), source, no_warmup, progress=False)
