"""best_time: the fastest of `repeats` timed calls, the warm-up untimed; bad repeats refused."""
import pytest

from neumat.core.errors import InputError
from neumat.testing import timing


def test_best_time_is_the_fastest_timed_call_and_skips_the_warm_up(monkeypatch):
    durations = iter([100.0, 5.0, 2.0, 7.0])  # the warm-up call is the slowest and must not count
    clock = [0.0]
    calls = []

    def fn():
        calls.append(1)
        clock[0] += next(durations)

    monkeypatch.setattr(timing.time, "perf_counter", lambda: clock[0])
    assert timing.best_time(fn, 3) == 2.0 and len(calls) == 4
    durations, calls[:] = iter([4.0, 3.0]), []
    assert timing.best_time(fn, 2, warmup=False) == 3.0 and len(calls) == 2


@pytest.mark.parametrize("bad", [0, -1, 2.5, True])
def test_best_time_refuses_bad_repeats(bad):
    with pytest.raises(InputError, match="repeats"):
        timing.best_time(lambda: None, bad)
