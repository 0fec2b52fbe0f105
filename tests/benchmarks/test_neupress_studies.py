"""benchmarks/studies/neupress/neupress_studies.py on tiny synthetic inputs (no Mitsuba, no images): the skip / layer
ablation and the baselines study give a row per variant, and their score is the held-out MSE over the held-out
variance."""
import importlib
from argparse import Namespace

import pytest
import torch

from neumat.fit.translucent_observations import Observations
from neumat.warp import sample_uniform_sphere

@pytest.fixture(scope="module")
def studies():
    return importlib.import_module("benchmarks.studies.neupress.neupress_studies")


def _observations(n, seed):
    g = torch.Generator().manual_seed(seed)
    x = sample_uniform_sphere(torch.rand(n, 2, generator=g))
    wi = sample_uniform_sphere(torch.rand(n, 2, generator=g))
    value = (0.05 + 0.05 * (wi * x).sum(-1, keepdim=True).clamp(min=0)) * (0.6 + 0.4 * x.abs())
    return Observations(x=x, n=x.clone(), wo=x.clone(), wi=wi, value=value)


def _setup(studies):
    return studies.Setup(data=_observations(600, 0), test=_observations(100, 1), floor=0.0)


def _args(**kw):
    return Namespace(**{**dict(layers=[2, 3], steps=4, batch=64, render_spp=1, models=["neupress", "dipole",
                                                                                       "dipole-textured"],
                               dipole_samples=16, dipole_steps=3, texture=2), **kw})


def test_skips_study_rows(studies):
    torch.set_num_threads(1)
    rows = studies.skips_study(_setup(studies), _args(layers=[1, 2], steps=2))
    assert [(r["skips"], r["layers"]) for r in rows] == [("on", 1), ("off", 1), ("on", 2), ("off", 2)]
    assert all(r["held-out / variance"] > 0 and r["fit s"] > 0 and r["best step"] is not None for r in rows)


def test_baselines_study_rows_and_score(studies):
    setup = _setup(studies)
    rows = studies.baselines_study(setup, _args())
    assert [r["model"] for r in rows] == ["neupress", "dipole", "dipole-textured"]
    assert rows[2]["KB fp16"] > rows[1]["KB fp16"] > 0  # the texture: 6 x 2^3 values more
    mean = setup.test.value.mean()

    class Constant:  # predicts the mean of all held-out values: scores 1 - 1/N (var is unbiased, the MSE is not)
        def eval(self, q):
            return mean.expand(len(q.wi), 3)
    n = setup.test.value.numel()
    assert studies.score(Constant(), setup, 1)["held-out / variance"] == pytest.approx(1 - 1 / n, rel=1e-5)
