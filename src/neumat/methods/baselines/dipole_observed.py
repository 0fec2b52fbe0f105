"""The dipole baseline as a function of observations: what its recipe (`neumat.methods.baselines.dipole_train`) fits
by L2 to path-traced observations (as NeuPreSS), through `neumat.fit.trainer.fit`."""
from __future__ import annotations

from neumat.methods.baselines.dipole_bssrdf import DipoleBSSRDF


def dipole_predict(model: DipoleBSSRDF):
    """S_hat of the model as a function of observations."""
    return lambda o: model.raw(o.wi, o.x, o.wo, o.n)
