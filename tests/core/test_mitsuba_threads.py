"""`mitsuba_threads`: Dr.Jit's worker threads inside the block, the caller's count after, also when it raises."""
from __future__ import annotations

import pytest

from neumat.core.errors import InputError
from neumat.core.mitsuba import mitsuba_threads
from tests.mitsuba_util import mitsuba_or_skip


@pytest.mark.mitsuba
def test_sets_the_count_inside_and_restores_it_after_also_on_error():
    mitsuba_or_skip()  # Dr.Jit loads its LLVM on import: only after the probe found a usable one
    import drjit as dr

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


def test_without_a_usable_llvm_it_says_so_and_leaves_none_alone(without_llvm):
    with mitsuba_threads(None):
        pass
    with pytest.raises(InputError, match="LLVM"), mitsuba_threads(1):
        pass
