"""marginal_rate: the rate between two batch sizes, measured again when a loaded machine's noise hides it."""
import math

import pytest
import torch

from neumat.core.query import Query
from neumat.testing import parity, timing


def _queries(n: int) -> Query:
    wi = torch.tensor([[0.0, 0.0, 1.0]]).expand(n, 3).contiguous()
    return Query(wi, wi.clone())


def test_marginal_rate_measures_again_when_the_larger_batch_looks_no_slower(monkeypatch):
    """Timings (larger batch, smaller batch) per attempt: the first pair is noise (no slower), the second a real
    difference of 0.7 s for 7/8 of 800 queries, so 1000 queries per second; all noise gives NaN."""
    times = iter([1.0, 1.0, 1.2, 0.5])
    monkeypatch.setattr(parity, "best_times", lambda fn, repeats, clocks: {k: next(times) for k in clocks})
    assert parity.marginal_rate(lambda q: None, _queries(800), "test") == pytest.approx(1000.0)
    times = iter([1.0, 1.0] * 3)
    assert math.isnan(parity.marginal_rate(lambda q: None, _queries(800), "test"))
    # both clocks from the same calls (wall, cpu per best_times): the wall clock succeeds at once, the CPU clock
    # at the second attempt and keeps that rate
    times = iter([1.2, 1.0, 0.5, 1.0, 9.0, 1.7, 2.0, 1.0])
    rates = parity.marginal_rate(lambda q: None, _queries(800), "test", clock="both")
    assert rates == {"wall": pytest.approx(1000.0), "cpu": pytest.approx(1000.0)}


def test_marginal_rate_on_a_real_workload_is_positive():
    rate = parity.marginal_rate(lambda q: torch.randn(len(q.wi) * 64).sort(), _queries(4096), "test")
    assert rate > 0
    both = parity.marginal_rate(lambda q: torch.randn(len(q.wi) * 64).sort(), _queries(4096), "test", "both")
    assert set(both) == {"wall", "cpu"} and all(x > 0 for x in both.values())


def test_best_times_reads_every_clock_around_the_same_calls():
    ticks = {"a": iter([0.0, 1.0, 5.0, 5.5]), "b": iter([0.0, 3.0, 10.0, 11.0])}
    calls = []
    best = timing.best_times(lambda: calls.append(1), 2, {k: (lambda k=k: next(ticks[k])) for k in ticks})
    assert best == {"a": 0.5, "b": 1.0} and len(calls) == 2


def test_the_drjit_rate_uploads_each_batch_size_once():
    """The Dr.Jit and Mitsuba rates' harness uploads a batch size's queries on its first call only, so that every
    timed call traces the same input variables (fresh uploads gave Dr.Jit new variable orders, and a compile every
    other call); each call still computes on the batch of its size."""
    from neumat.testing import drjit_parity

    uploads, calls = [], []
    run = drjit_parity._uploaded_once(lambda part: uploads.append(len(part.wi)) or (len(part.wi), "x"),
                                      lambda size, x: calls.append(size))
    q = _queries(800)
    for part in (q[:64], q[:100], q, q[:100], q, q):
        run(part)
    assert uploads == [64, 100, 800] and calls == [64, 100, 800, 100, 800, 800]
