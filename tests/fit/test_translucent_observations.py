"""Observations of a path-traced translucent object: geometry of the views, values, file round trip."""
import math

import numpy as np
import pytest
import torch

from neumat import InputError
from neumat.core.errors import DataFormatError
from neumat.fit.translucent_observations import Observations, collect_observations
from tests.mitsuba_util import mitsuba_or_skip


@pytest.mark.mitsuba
def test_collect_observations_on_the_unit_sphere(tmp_path):
    mitsuba_or_skip()
    from neumat.reflectance.translucent import TranslucentObject
    obj = TranslucentObject(spp=4)
    obs = collect_observations(obj, images=3, resolution=8)
    assert 0 < len(obs) <= 3 * 64
    assert torch.allclose(obs.x.norm(dim=-1), torch.ones(len(obs)), atol=1e-5)  # points on the surface
    assert torch.allclose(obs.n, obs.x, atol=1e-4)  # outward normals of the sphere
    assert bool(((obs.n * obs.wo).sum(-1) > 0).all())  # seen from outside
    assert len(torch.unique(obs.wi, dim=0)) == 3  # one light per view
    assert bool(torch.isfinite(obs.value).all()) and float(obs.value.mean()) > 0
    obs.save(tmp_path / "o.npz", source={"object": {"media": ["marble", "ketchup"]}})
    back = Observations.load(tmp_path / "o.npz")
    assert torch.equal(back.value, obs.value) and torch.equal(back.x, obs.x)
    assert Observations.load_source(tmp_path / "o.npz") == {"object": {"media": ["marble", "ketchup"]}}
    obs.save(tmp_path / "plain.npz")
    assert Observations.load_source(tmp_path / "plain.npz") is None
    rest, held = obs.split(0.25)
    assert len(rest) + len(held) == len(obs) and len(held) == round(0.25 * len(obs))


def test_observations_bad_input(tmp_path):
    x = torch.zeros(4, 3)
    with pytest.raises(InputError, match="Observations.value"):
        Observations(x=x, n=x, wo=x, wi=x, value=torch.zeros(4, 2))
    with pytest.raises(InputError, match="non-finite"):
        Observations(x=x, n=x, wo=x, wi=x, value=torch.full((4, 3), float("nan")))
    with pytest.raises(InputError, match="does not exist"):
        Observations.load(tmp_path / "missing.npz")
    np.savez(tmp_path / "other.npz", x=np.zeros((4, 3)))
    with pytest.raises(DataFormatError, match="observations"):
        Observations.load(tmp_path / "other.npz")
    with pytest.raises(InputError, match="images"):
        collect_observations(None, images=0)


def test_negative_values_are_legitimate_but_not_a_negative_mean(tmp_path):
    """A value is a difference of two Monte Carlo traces, so some are negative (kept, unclamped); a channel whose
    mean lies far below 0 cannot be such data and is refused."""
    g = torch.Generator().manual_seed(0)
    up = torch.tensor([[0.0, 0.0, 1.0]]).repeat(400, 1)
    noisy = 0.05 + 0.2 * torch.randn(400, 3, generator=g)  # about 40% negative, mean 0.05
    assert float((noisy < 0).float().mean()) > 0.3
    Observations(up, up, up, up, noisy).save(tmp_path / "noisy.npz")
    assert torch.equal(Observations.load(tmp_path / "noisy.npz").value, noisy)
    shifted = noisy.clone()
    shifted[:, 1] -= 0.2  # green's mean -0.15: 10 standard errors below 0
    Observations(up, up, up, up, shifted).save(tmp_path / "shifted.npz")
    with pytest.raises(DataFormatError, match="channel G is -0.1.*standard errors below 0"):
        Observations.load(tmp_path / "shifted.npz")


@pytest.mark.parametrize("source,match", [([1], "expected a JSON object"), ({"spp": 0}, "'spp' must be a positive"),
                                          ({"bbox": [[0, 0, 0], [1, 1, True]]}, "'bbox'"),
                                          ({"object": {"media": 5}}, "TranslucentConfig.media"),
                                          ({"noise": []}, "'noise' must be a JSON object")])
def test_a_malformed_source_is_refused(tmp_path, source, match):
    up = torch.tensor([[0.0, 0.0, 1.0]]).repeat(4, 1)
    Observations(up, up, up, up, up).save(tmp_path / "o.npz", source=source)
    for read in (Observations.load, Observations.load_source):
        with pytest.raises(DataFormatError, match=match):
            read(tmp_path / "o.npz")


@pytest.mark.mitsuba
def test_a_cut_off_trace_resumes_to_the_uninterrupted_result(tmp_path):
    """A trace checkpointed after every view and cut off at its third view, resumed by a fresh object, gives the
    observations the uninterrupted trace gives; the checkpoint is gone at the end; another trace's checkpoint, or a
    broken file, is refused with a line naming it."""
    mitsuba_or_skip()
    from neumat.reflectance.translucent import TranslucentObject
    uninterrupted = TranslucentObject(spp=2, seed=3)
    whole = collect_observations(uninterrupted, images=5, resolution=6, seed=1)
    assert uninterrupted.trace_cpu_seconds > 0  # what the observations cost, counted by `trace`
    ckpt = tmp_path / "trace.ckpt"
    cut = TranslucentObject(spp=2, seed=3)
    calls, real = [], cut.trace

    def trace_until_the_third(*args, **kwargs):
        calls.append(1)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return real(*args, **kwargs)
    cut.trace = trace_until_the_third
    with pytest.raises(KeyboardInterrupt):
        collect_observations(cut, images=5, resolution=6, seed=1, checkpoint=ckpt, checkpoint_every_s=0)
    assert ckpt.is_file()
    with pytest.raises(InputError, match="another trace.*resolution"):
        collect_observations(TranslucentObject(spp=2, seed=3), images=5, resolution=7, seed=1, checkpoint=ckpt,
                             resume=True)
    stale = tmp_path / "stale.ckpt"  # a checkpoint written before it recorded CPU seconds
    blob = torch.load(ckpt, weights_only=True)
    blob.pop("cpu_seconds")
    torch.save(blob, stale)
    old = TranslucentObject(spp=2, seed=3)
    collect_observations(old, images=5, resolution=6, seed=1, checkpoint=stale, resume=True)
    assert math.isnan(old.trace_cpu_seconds)  # unknown, not an undercount
    again = TranslucentObject(spp=2, seed=3)
    resumed = collect_observations(again, images=5, resolution=6, seed=1, checkpoint=ckpt, resume=True)
    assert again.trace_cpu_seconds > cut.trace_cpu_seconds > 0  # the cut trace's CPU carried over
    assert not ckpt.exists()
    for name in ("x", "n", "wo", "wi", "value"):
        assert torch.equal(getattr(resumed, name), getattr(whole, name)), name
    ckpt.write_bytes(b"not a checkpoint")
    with pytest.raises(DataFormatError, match="trace checkpoint"):
        collect_observations(TranslucentObject(spp=2, seed=3), images=5, resolution=6, seed=1, checkpoint=ckpt,
                             resume=True)
    with pytest.raises(InputError, match="resume needs a checkpoint"):
        collect_observations(None, images=5, resume=True)
