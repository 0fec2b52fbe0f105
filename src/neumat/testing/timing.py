"""Wall-clock timing for benchmarks and throughput checks: the best of a few calls."""
from __future__ import annotations

import time
from typing import Callable

import torch

from ..core.checks import check_int


def best_times(fn: Callable[[], object], repeats: int, clocks: dict[str, Callable[[], float]]) -> dict[str, float]:
    """Seconds of the fastest of `repeats` calls of fn() (no warm-up, no gradients) on each of `clocks` ({name:
    clock}), all read around the same calls: a wall and a CPU rate from one set of runs."""
    check_int(repeats, "best_times repeats", 1)
    best = {name: float("inf") for name in clocks}
    with torch.no_grad():
        for _ in range(repeats):
            start = {name: clock() for name, clock in clocks.items()}
            fn()
            for name, clock in clocks.items():
                best[name] = min(best[name], clock() - start[name])
    return best


def best_time(fn: Callable[[], object], repeats: int = 3, warmup: bool = True,
              clock: Callable[[], float] | None = None) -> float:
    """Seconds of the fastest of `repeats` calls of fn() (after one untimed warm-up call unless `warmup` is
    False), without gradients: the least disturbed run on a shared machine. `clock`: wall (None:
    time.perf_counter) or, say, `time.process_time` (CPU seconds of every thread of this process: a loaded machine's
    waits do not count)."""
    check_int(repeats, "best_time repeats", 1)
    if warmup:
        with torch.no_grad():
            fn()
    return best_times(fn, repeats, {"clock": clock or time.perf_counter})["clock"]
