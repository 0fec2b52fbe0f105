"""MeasuredSamples: exact answers for replayed queries, nearest-sample answers otherwise, validation."""
from __future__ import annotations

import pytest
import torch

from neumat.core.errors import InputError
from neumat.core.query import Query
from neumat.fit.measured_samples import MeasuredSamples


def _dirs(n: int, gen: torch.Generator) -> torch.Tensor:
    v = torch.randn(n, 3, generator=gen, dtype=torch.float64)
    v[:, 2] = v[:, 2].abs() + 0.1
    return (v / v.norm(dim=-1, keepdim=True)).float()


def test_query_of_stored_samples_is_exact_and_others_take_nearest(gen):
    wi, wo = _dirs(50, gen), _dirs(50, gen)
    value = torch.rand(50, 3, generator=gen)
    s = MeasuredSamples(wi, wo, value, name="sparse")
    idx = torch.tensor([3, 3, 49, 0])
    assert torch.equal(s.eval(s.query(idx)), value[idx])
    # a plain query at the stored directions, slightly perturbed, finds the same samples
    jitter = lambda w: torch.nn.functional.normalize(w + 1e-4, dim=-1)  # noqa: E731
    q = Query(jitter(wi[idx]), jitter(wo[idx]))
    assert torch.equal(s.nearest(q), idx)
    assert torch.equal(s.eval(q), value[idx])
    # brute-force reference for random queries
    q = Query(_dirs(300, gen), _dirs(300, gen))
    d = ((q.wi[:, None] - wi[None]) ** 2).sum(-1) + ((q.wo[:, None] - wo[None]) ** 2).sum(-1)
    assert torch.equal(s.nearest(q), d.argmin(-1))
    assert s.nearest(Query(wi[:0], wo[:0])).shape == (0,)
    assert "50 measured samples" in s.describe()


def test_from_material_and_spatially_varying(gen):
    class Uv:
        def eval(self, q):
            return torch.cat([q.uv, q.uv[:, :1]], -1)

        def describe(self):
            return "uv material"

    q = Query(_dirs(20, gen), _dirs(20, gen), uv=torch.rand(20, 2, generator=gen))
    s = MeasuredSamples.from_material(Uv(), q)
    assert s.spatially_varying and s.name == "samples of uv material"
    assert torch.equal(s.eval(Query(q.wi, q.wo, uv=q.uv)), Uv().eval(q))
    with pytest.raises(InputError, match="uv"):
        s.eval(Query(q.wi, q.wo))


@pytest.mark.parametrize("change, match", [
    (dict(value=torch.ones(5, 2)), "value"),
    (dict(value=torch.full((5, 3), float("nan"))), "non-finite"),
    (dict(wi=torch.ones(5, 3)), "unit length"),
    (dict(wo=torch.tensor([[0.0, 0.0, -1.0]] * 5)), "upper hemisphere"),
    (dict(uv=torch.full((5, 2), 2.0)), "uv"),
    (dict(wi=torch.zeros(0, 3), wo=torch.zeros(0, 3), value=torch.zeros(0, 3)), "at least one"),
])
def test_bad_samples_raise(change, match, gen):
    args = dict(wi=_dirs(5, gen), wo=_dirs(5, gen), value=torch.ones(5, 3))
    args.update(change)
    with pytest.raises(InputError, match=match):
        MeasuredSamples(**args)


def test_reciprocal_adds_each_sample_with_its_directions_exchanged(gen):
    """`reciprocal()`: 2N samples, the first N these, the rest with wi and wo exchanged and the same values (a
    BRDF's reciprocity), uv carried along; replayed queries of the exchanged ones are answered exactly."""
    wi, wo, uv = _dirs(30, gen), _dirs(30, gen), torch.rand(30, 2, generator=gen)
    value = torch.rand(30, 3, generator=gen)
    both = MeasuredSamples(wi, wo, value, uv=uv, name="sparse").reciprocal()
    assert len(both) == 60 and both.name == "sparse and their reciprocals" and both.spatially_varying
    assert torch.equal(both.wi, torch.cat([wi, wo])) and torch.equal(both.wo, torch.cat([wo, wi]))
    assert torch.equal(both.value, torch.cat([value, value])) and torch.equal(both.uv, torch.cat([uv, uv]))
    idx = torch.tensor([31, 0, 59])
    q = both.query(idx)
    assert torch.equal(q.wi[0], wo[1]) and torch.equal(q.wo[0], wi[1]) and torch.equal(both.eval(q), value[[1, 0, 29]])
    assert MeasuredSamples(wi, wo, value).reciprocal().uv is None
