"""Translucent-object fits through the one trainer resume bit for bit: NeuPreSS (appearance with early stopping,
then the light sampler) from a checkpoint written in either phase, the dipole (one phase with early stopping)
from one written mid-phase; and their sources are checked."""
from __future__ import annotations

import pytest
import torch

from neumat import InputError
from neumat.fit.method import recipe_for
from neumat.fit.trainer import fit
from neumat.fit.translucent_observations import Observations
from neumat.methods.baselines.dipole_bssrdf import DipoleBSSRDF
from neumat.methods.neupress.model import NeuPreSS
from neumat.warp import sample_uniform_sphere


class Interrupt(Exception):
    pass


def _observations(n=400, seed=0):
    g = torch.Generator().manual_seed(seed)
    x = sample_uniform_sphere(torch.rand(n, 2, generator=g))
    wi = sample_uniform_sphere(torch.rand(n, 2, generator=g))
    value = (0.5 + 0.5 * (wi * x).sum(-1, keepdim=True)) * (0.6 + 0.4 * x.abs()) * (1 + torch.rand(n, 1, generator=g))
    return Observations(x=x, n=x.clone(), wo=x.clone(), wi=wi, value=value)


def _neupress(obs, **kw):
    torch.manual_seed(0)
    m = NeuPreSS(features=8, width=16, layers=3, sampler_hidden=(8,))
    r = recipe_for("neupress")
    r.steps, r.phase_split, r.batch_size, r.log_every, r.checkpoint_every = 20, (0.6, 0.4), 64, 4, 3
    r.options.update(validation_fraction=0.25, sampler_batch=4, grid=[4, 8])
    return m, fit(m, obs, r, progress=False, **kw)


def _dipole(obs, **kw):
    torch.manual_seed(0)
    m = DipoleBSSRDF(samples=64)
    g = torch.Generator().manual_seed(1)
    p = sample_uniform_sphere(torch.rand(64, 2, generator=g))
    m.set_surface(p, p.clone(), torch.full((64,), 4 * torch.pi / 64))
    r = recipe_for("dipole-bssrdf")
    r.steps, r.batch_size, r.log_every, r.checkpoint_every = 20, 32, 4, 3
    r.options.update(validation_fraction=0.25)
    return m, fit(m, obs, r, progress=False, **kw)


def _strip(history):
    return [{k: v for k, v in r.items() if k != "seconds"} for r in history]


@pytest.mark.parametrize("run, stop, saved, phase", [
    (_neupress, 8, 6, "appearance"),   # between two validation points of the appearance phase
    (_neupress, 16, 15, "sampler"),    # after the best weights were restored, mid-sampler
    (_dipole, 8, 6, "fit"),            # mid-phase, between two validation points
    (_dipole, 12, 12, "fit"),          # at a validation point (measured by the resumed run)
])
def test_resume_equals_uninterrupted_run(tmp_path, run, stop, saved, phase):
    obs = _observations()
    ref_model, ref = run(obs)

    def stop_at(record):
        if record["step"] == stop:
            raise Interrupt

    ckpt = tmp_path / "fit.ckpt"
    with pytest.raises(Interrupt):
        run(obs, checkpoint=ckpt, callback=stop_at)
    blob = torch.load(ckpt, weights_only=True)
    assert blob["step"] == saved and (saved > 12) == (phase == "sampler")  # NeuPreSS: appearance is steps 1-12
    model, res = run(obs, checkpoint=ckpt, resume=True)
    ref_state, state = ref_model.state_dict(), model.state_dict()
    assert ref_state.keys() == state.keys()
    for k in ref_state:
        assert torch.equal(ref_state[k], state[k]), k
    assert _strip(res.history) == _strip(ref.history)
    validated = [r["step"] for r in res.history if "validation_mse" in r]
    assert validated == [4, 8, 12] + [16, 20] * (run is _dipole)


def test_sources_are_checked():
    obs = _observations(40)
    m = NeuPreSS(features=8, width=16, layers=3, sampler_hidden=(8,))
    for source in (DipoleBSSRDF(samples=8), "obs.npz", obs.value):
        with pytest.raises(InputError, match="Observations"):
            fit(m, source, recipe_for("neupress", "paper"), steps=2, progress=False)
    with pytest.raises(InputError, match=r"^dipole-bssrdf recipe options: option.validation_fraction: expected a "
                                         r"value in \[0, 1\), got 1.5$"):
        r = recipe_for("dipole-bssrdf")
        r.options["validation_fraction"] = 1.5
        fit(DipoleBSSRDF(samples=8), obs, r, steps=2, progress=False)
