"""Fitting the dipole baseline's six coefficients to path-traced observations (L2, as NeuPreSS)."""
from __future__ import annotations

from ..models.dipole_bssrdf import DipoleBSSRDF
from .translucent_fit import fit_observations
from .translucent_observations import Observations


def fit_dipole(model: DipoleBSSRDF, observations: Observations, steps: int = 300, batch: int = 256,
               lr: float = 0.05, seed: int = 0, progress: bool = False, log_every: int = 20,
               validation: Observations | None = None) -> list[dict]:
    """Adam on log sigma_a, log sigma_s' (lr halved at 50% / 75%); `validation` as in `fit_observations`. The
    model needs its surface quadrature (`DipoleBSSRDF.set_surface`) first."""
    return fit_observations(dipole_predict(model), [model.log_sigma_a, model.log_sigma_s], observations, steps,
                            batch, lr, seed, progress, log_every, validation, "dipole BSSRDF")


def dipole_predict(model: DipoleBSSRDF):
    """S_hat of the model as a function of observations."""
    return lambda o: model.raw(o.wi, o.x, o.wo, o.n)
