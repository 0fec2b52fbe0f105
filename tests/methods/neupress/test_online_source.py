"""NeuPreSS's online (Mitsuba-in-the-loop) and hybrid sources: fresh batches reproducible from (seed, step),
unbiased against a long trace, end to end through `neumat fit`, resumed bit for bit mid-online, and their errors."""
from __future__ import annotations

import pytest
import torch
from typer.testing import CliRunner

from neumat import InputError
from neumat.cli.main import app
from neumat.core.query import Query
from neumat.fit.method import recipe_for
from neumat.fit.trainer import fit
from neumat.fit.translucent_observations import Observations
from neumat.methods.neupress.model import NeuPreSS
from neumat.warp import sample_uniform_sphere
from tests.mitsuba_util import mitsuba_or_skip

#: tiny model and recipe sizes (the method's `small` sizes as --set overrides)
SMALL = ["features=16", "width=16", "layers=2", "sampler_hidden=8"]


class Interrupt(Exception):
    pass


def _sphere(spp=2):
    from neumat.reflectance.translucent import TranslucentObject
    return TranslucentObject(spp=spp)


def _traced(tmp_path) -> Observations:
    """A tiny observations file of the default sphere, with its object description (as `translucent trace`)."""
    from neumat.core.config import config_to_dict
    from neumat.fit.translucent_observations import collect_observations
    obj = _sphere()
    obs = collect_observations(obj, images=6, resolution=8, spp=2)
    path = tmp_path / "o.npz"
    obs.save(path, source={"object": config_to_dict(obj.config), "spp": 2, "seed": 0,
                           "bbox": [obj.bbox_min.tolist(), obj.bbox_max.tolist()]})
    return path


@pytest.mark.mitsuba
def test_draw_is_reproducible_per_step_and_fresh_across_steps():
    mitsuba_or_skip()
    from neumat.fit.translucent_online import OnlineObservations
    obj = _sphere()
    source = OnlineObservations(obj, resolution=8, spp=2, seed=3)
    calls = obj.trace_calls
    a, b, c = source.draw(5, 150), source.draw(5, 150), source.draw(6, 150)
    assert len(a) == len(c) == 150  # exactly n, from several views (a view has at most 64 rays)
    for name in ("x", "n", "wo", "wi", "value"):
        assert torch.equal(getattr(a, name), getattr(b, name)), name
    assert not torch.equal(a.wi, c.wi) and not torch.equal(a.value, c.value)
    assert len(torch.unique(a.wi, dim=0)) >= 3  # one light per view
    assert torch.allclose(a.x.norm(dim=-1), torch.ones(150), atol=1e-5) and bool(((a.n * a.wo).sum(-1) > 0).all())
    assert obj.trace_calls == calls  # seeded traces leave the object's own call-counter stream alone
    other = OnlineObservations(obj, resolution=8, spp=2, seed=4).draw(5, 150)
    assert not torch.equal(a.value, other.value)


@pytest.mark.mitsuba
def test_online_values_are_unbiased():
    """The mean of the online values over a batch agrees with an independent 256-spp trace of the same queries."""
    mitsuba_or_skip()
    from neumat.fit.translucent_online import OnlineObservations
    from neumat.reflectance.translucent import TranslucentObject
    obj = _sphere()
    online = OnlineObservations(obj, resolution=8, spp=4, seed=1).draw(0, 400)
    reference = TranslucentObject(obj.config, spp=256, seed=99)
    long = reference.eval(Query(x=online.x.double(), wo=online.wo.double(), wi=online.wi.double())).float()
    diff = (online.value - long).double()
    z = diff.mean(0) / (diff.std(0) / len(diff) ** 0.5)
    assert float(long.mean()) > 0.01
    assert bool((z.abs() < 4).all()), z


@pytest.mark.mitsuba
@pytest.mark.parametrize("mode", ["online", "hybrid"])
def test_cli_fit_traces_online(tmp_path, mode):
    mitsuba_or_skip()
    obs = _traced(tmp_path)
    sets = [*SMALL, f"option.source={mode}", "option.online_spp=2", "option.online_resolution=8",
            "option.warm_fraction=0.5", "batch_size=64", "log_every=2", "phase_split=[0.75,0.25]",
            "option.validation_fraction=0.2"]
    out = tmp_path / "m.nmat"
    r = CliRunner().invoke(app, ["fit", str(obs), "--model", "neupress", "-o", str(out), "--steps", "8",
                                 "--device", "cpu", *[a for s in sets for a in ("--set", s)]])
    assert r.exit_code == 0, r.output
    assert out.is_file() and "validation" in r.output
    if mode == "hybrid":  # the switch to the slow online steps is said and the estimate measured again
        assert "turns slower at step 3" in " ".join(r.output.split())


def _hybrid_fit(obs, **kw):
    torch.manual_seed(0)
    m = NeuPreSS(features=8, width=16, layers=2, sampler_hidden=(8,))
    r = recipe_for("neupress")
    r.steps, r.phase_split, r.batch_size, r.log_every, r.checkpoint_every = 12, (0.75, 0.25), 48, 2, 3
    r.options.update(validation_fraction=0.2, sampler_batch=4, grid=[4, 8], source="hybrid", warm_fraction=0.34,
                     online_spp=2, online_resolution=8)
    return m, fit(m, obs, r, progress=False, **kw)


@pytest.mark.mitsuba
def test_resume_mid_online_equals_uninterrupted_run(tmp_path):
    """Appearance steps 1-9 (offline 1-3, online 4-9), sampler 10-12; interrupted after step 6, resumed from the
    checkpoint of step 6 (online), the fit re-traces the same batches and ends bit for bit as the uninterrupted one."""
    mitsuba_or_skip()
    obs = Observations.load(_traced(tmp_path))
    ref_model, ref = _hybrid_fit(obs)

    def stop_at(record):
        if record["step"] == 6:
            raise Interrupt

    ckpt = tmp_path / "fit.ckpt"
    with pytest.raises(Interrupt):
        _hybrid_fit(obs, checkpoint=ckpt, callback=stop_at)
    assert torch.load(ckpt, weights_only=True)["step"] == 6
    model, res = _hybrid_fit(obs, checkpoint=ckpt, resume=True)
    for k, v in ref_model.state_dict().items():
        assert torch.equal(v, model.state_dict()[k]), k
    strip = [{k: v for k, v in r.items() if k != "seconds"} for r in res.history]
    assert strip == [{k: v for k, v in r.items() if k != "seconds"} for r in ref.history]


def _plain(n=40):
    g = torch.Generator().manual_seed(0)
    x = sample_uniform_sphere(torch.rand(n, 2, generator=g))
    return Observations(x=x, n=x.clone(), wo=x.clone(), wi=x.flip(0).clone(), value=torch.rand(n, 3, generator=g))


@pytest.mark.parametrize("option, value, message", [
    ("source", "sometimes", "option.source: expected one of 'offline', 'online', 'hybrid', got 'sometimes'"),
    ("warm_fraction", 1.5, r"option.warm_fraction: expected a value in \[0, 1\], got 1.5"),
    ("online_spp", 0, "option.online_spp: expected a value >= 1, got 0"),
    ("online_resolution", 0, "option.online_resolution: expected a value >= 1, got 0"),
])
def test_bad_options_are_refused(option, value, message):
    r = recipe_for("neupress")
    r.options[option] = value
    with pytest.raises(InputError, match=f"^neupress recipe options: {message}$"):
        fit(NeuPreSS(features=8, width=16, layers=2, sampler_hidden=(8,)), _plain(), r, steps=2, progress=False)


@pytest.mark.parametrize("mode", ["online", "hybrid"])
def test_observations_without_an_object_description_are_refused(mode):
    r = recipe_for("neupress")
    r.options["source"] = mode
    with pytest.raises(InputError, match=f"^fit neupress option.source={mode}: tracing online needs the object "
                                         r"the observations were traced from, .*\(write them with `neumat "
                                         r"translucent trace`\)$"):
        fit(NeuPreSS(features=8, width=16, layers=2, sampler_hidden=(8,)), _plain(), r, steps=2, progress=False)
