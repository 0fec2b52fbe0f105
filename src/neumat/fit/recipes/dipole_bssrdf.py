"""Training recipe of the dipole baseline of NeuPreSS (Jensen et al. 2001 over a surface quadrature): its six
coefficients (log sigma_a, log sigma_s') fitted by L2 to path-traced observations, as NeuPreSS's appearance
phase (`neumat.fit.translucent_fit`): Adam lr 0.05 halved at 50 % and 75 %, 300 steps of 256 observations,
5 % held back for early stopping, of which at most 4096 are used (each evaluation sums over the whole surface
quadrature: 1.9e3 queries/s in benchmarks/results/neupress.md). The model needs its surface quadrature
(`DipoleBSSRDF.set_surface`) before the fit.
"""
from __future__ import annotations

from neumat.fit.dipole_bssrdf import dipole_predict
from neumat.fit.phase import FitContext, Phase
from neumat.fit.recipe import Recipe
from neumat.fit.translucent_fit import observation_phase, split_observations

RECIPE = Recipe(steps=300, batch_size=256, lr=0.05, schedule="halves", loss="l2", log_every=20,
                options={"validation_fraction": 0.05, "max_validation": 4096, "bounds": None})


def phases(ctx: FitContext) -> list[Phase]:
    model = ctx.model
    train, validation = split_observations(ctx)
    (steps,) = ctx.split(("fit",))
    return [observation_phase(ctx, "fit", steps, dipole_predict(model), [model.log_sigma_a, model.log_sigma_s],
                              train, validation)]
