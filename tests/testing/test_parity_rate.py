"""marginal_rate: the rate between two batch sizes, measured again when a loaded machine's noise hides it."""
import math

import pytest
import torch

from neumat.core.query import Query
from neumat.testing import parity


def _queries(n: int) -> Query:
    wi = torch.tensor([[0.0, 0.0, 1.0]]).expand(n, 3).contiguous()
    return Query(wi, wi.clone())


def test_marginal_rate_measures_again_when_the_larger_batch_looks_no_slower(monkeypatch):
    """Timings (larger batch, smaller batch) per attempt: the first pair is noise (no slower), the second a real
    difference of 0.7 s for 7/8 of 800 queries, so 1000 queries per second; all noise gives NaN."""
    times = iter([1.0, 1.0, 1.2, 0.5])
    monkeypatch.setattr(parity, "best_time", lambda fn, repeats, warmup, clock: next(times))
    assert parity.marginal_rate(lambda q: None, _queries(800), "test") == pytest.approx(1000.0)
    times = iter([1.0, 1.0] * 3)
    assert math.isnan(parity.marginal_rate(lambda q: None, _queries(800), "test"))


def test_marginal_rate_on_a_real_workload_is_positive():
    rate = parity.marginal_rate(lambda q: torch.randn(len(q.wi) * 64).sort(), _queries(4096), "test")
    assert rate > 0
