import pytest
import torch

from neumat.core.errors import InputError
from neumat.core.material import sample_weight
from neumat.core.query import Query


def test_query_validates_inputs():
    wi = torch.tensor([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8]])
    q = Query(wi, wi.flip(0))
    assert len(q) == 2 and q.swapped().wi.equal(wi.flip(0))
    assert len(q[torch.tensor([True, False])]) == 1
    with pytest.raises(InputError, match="Query.wi: expected shape"):
        Query(torch.zeros(3))
    with pytest.raises(InputError, match="unit length"):
        Query(torch.ones(2, 3))
    with pytest.raises(InputError, match="non-finite"):
        Query(torch.tensor([[float("nan"), 0.0, 1.0]]))
    with pytest.raises(InputError, match="Query.uv: expected shape \\(2, 2\\)"):
        Query(wi, wi, uv=torch.zeros(3, 2))
    with pytest.raises(InputError, match="needs Query.uv"):
        q.require("uv")


def test_sample_weight_zero_where_invalid():
    f = torch.ones(3, 3)
    wo = torch.tensor([[0.0, 0.0, 1.0]] * 3)
    pdf = torch.tensor([0.5, 0.0, 2.0])
    w = sample_weight(f, wo, pdf, torch.tensor([True, True, False]))
    assert torch.equal(w, torch.tensor([[2.0] * 3, [0.0] * 3, [0.0] * 3]))


def test_trusted_query_skips_validation_but_behaves_like_a_query():
    wi = torch.tensor([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8]])
    q = Query.trusted(wi, wi.flip(0))
    assert torch.equal(q.wi, wi) and torch.equal(q.wo, wi.flip(0)) and q.uv is None and len(q) == 2
    assert torch.equal(q.swapped().wi, wi.flip(0))  # the usual methods work on it
    bad = torch.tensor([[0.0, 0.0, 2.0]])
    Query.trusted(bad)  # no check: the caller vouches for its tensors
    with pytest.raises(InputError, match="unit length"):
        Query(bad)


def test_with_wo_checks_the_new_directions_and_keeps_the_rest():
    wi = torch.tensor([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8]])
    uv = torch.rand(2, 2)
    q = Query(wi, uv=uv).with_wo(wi.flip(0))
    assert isinstance(q, Query) and torch.equal(q.wo, wi.flip(0)) and q.uv is uv and q.wi is wi
    assert q.with_wo(None).wo is None and q.wo is not None
    with pytest.raises(InputError, match="unit length"):
        Query(wi).with_wo(torch.ones(2, 3))
    with pytest.raises(InputError, match="non-finite"):
        Query(wi).with_wo(torch.tensor([[float("nan"), 0.0, 1.0]] * 2))
    with pytest.raises(InputError, match=r"Query.wo: expected shape \(2, 3\)"):
        Query(wi).with_wo(wi[:1])
    with pytest.raises(InputError, match="float64"):
        Query(wi).with_wo(wi.double())


def test_queries_derived_from_a_checked_query_are_not_checked_again_but_odd_indices_are(monkeypatch):
    """Sub-batches, swaps and a no-op `to` of a checked query reuse its checks (the fast path of evaluation
    loops); an int index, whose fields lose a dimension, still gives one clear InputError."""
    wi = torch.tensor([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8], [0.0, 0.8, 0.6]])
    q = Query(wi, wi.flip(0), uv=torch.rand(3, 2))
    assert q.to(dtype=torch.float32) is q and q.to("cpu") is q
    assert q.to(dtype=torch.float64).wi.dtype == torch.float64
    calls = []
    monkeypatch.setattr(Query, "__post_init__", lambda self: calls.append(1))
    for sub in (q[1:], q[torch.tensor([True, False, True])], q[torch.tensor([2, 0])], q.swapped()):
        assert isinstance(sub, Query) and sub.uv is not None and sub.wi.shape[0] == sub.uv.shape[0]
    assert torch.equal(q[torch.tensor([2, 0])].wo, wi.flip(0)[[2, 0]]) and torch.equal(q.swapped().wo, wi)
    assert not calls
    monkeypatch.undo()
    with pytest.raises(InputError, match="Query.wi: expected shape"):
        q[0]


def test_direction_checks_catch_non_finite_and_non_unit_values_with_their_own_messages():
    for bad, message in (([[float("inf"), 0.0, 1.0]], "non-finite"), ([[0.0, float("nan"), 1.0]], "non-finite"),
                         ([[0.0, 0.0, 1.01]], "unit length")):
        with pytest.raises(InputError, match=message):
            Query(torch.tensor([[0.0, 0.0, 1.0]]), torch.tensor(bad))
        with pytest.raises(InputError, match=message):
            Query(torch.tensor(bad))
