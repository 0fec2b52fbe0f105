"""Issue requirement: NeuBRDF fitted to an analytic GGX reaches a stated HDR error within a few hundred CPU steps."""
from __future__ import annotations

from dataclasses import replace

import pytest
import torch

from neumat.fit.method import recipe_for
from neumat.fit.trainer import fit
from neumat.metrics.hdr import reflectance_errors
from neumat.methods.neubrdf.model import NeuBRDF
from neumat.reflectance.analytic import GGX

# measured in runtime form (seed 0, 300 steps of 4096, recipe lr 1e-2): vq rel 0.30 / log 0.026,
# dense rel 0.16 / log 0.013; bounds leave ~25 % for platform differences. The best gold-tinted Lambert
# scores rel 0.73 on this source (its specular peak carries most of the energy).
BOUNDS = {"vq": (0.38, 0.032), "dense": (0.20, 0.017)}


@pytest.mark.parametrize("features", ["vq", pytest.param("dense", marks=pytest.mark.slow)])
def test_neubrdf_fits_gold_ggx(features):
    source = GGX(roughness=0.3, material="gold")
    torch.manual_seed(0)
    model = NeuBRDF(nside=8, index_bits=6, hidden=32, features=features)
    recipe = replace(recipe_for("neubrdf"), batch_size=4096, ema=0.05, lr_decay_every=0)
    fit(model, source, recipe, steps=300, progress=False)
    errors = reflectance_errors(model.runtime(), source, n=2 ** 16, seed=3)
    rel, log = BOUNDS[features]
    assert errors["rel_err"] < rel and errors["log_err"] < log, errors
