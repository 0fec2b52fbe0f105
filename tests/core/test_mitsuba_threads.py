"""`mitsuba_threads`: Dr.Jit's worker threads inside the block, the caller's count after, also when it raises."""
from __future__ import annotations

import pytest

from neumat.core.mitsuba import mitsuba_threads


def test_sets_the_count_inside_and_restores_it_after_also_on_error():
    dr = pytest.importorskip("drjit", reason="Dr.Jit (the mitsuba package) is not installed")
    before = dr.thread_count()
    inside = 1 if before != 1 else 2
    with mitsuba_threads(inside):
        assert dr.thread_count() == inside
    assert dr.thread_count() == before
    with pytest.raises(RuntimeError), mitsuba_threads(inside):
        raise RuntimeError("the block failed")
    assert dr.thread_count() == before
    with mitsuba_threads(None):  # left alone
        assert dr.thread_count() == before
