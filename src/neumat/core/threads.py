"""torch's intra-op threads beside other work on the machine: a command given no thread count takes the cores that
other processes leave free, and a fit keeps doing so while it runs (`shared_threads`, `adapt`). Why: torch's OpenMP
threads wait for each other by spinning, so a thread without a core of its own stalls every operation (measured on
2 cores beside one busy process: 180 ms a NeuBRDF-sized training step on 2 threads, 11 ms on 1; idle 7 and 8.5 ms).
Linux only (/proc); elsewhere the count is unknown and torch's own stays."""
from __future__ import annotations

import os
import time
from contextlib import contextmanager
from typing import Iterator

import torch

#: seconds between two looks at the machine during a fit (each costs about 20 ms: 0.2 % of the fit's time)
CHECK_EVERY_S = 10.0


def runnable_tasks() -> int | None:
    """Tasks running or ready to run on the whole machine now (/proc/loadavg's fourth field); None outside Linux."""
    try:
        with open("/proc/loadavg") as f:
            return int(f.read().split()[3].split("/")[0])
    except (OSError, ValueError, IndexError):
        return None


def own_runnable_threads() -> int:
    """Threads of this process running or ready to run now (state R in /proc/self/task/*/stat), this one included."""
    count = 0
    try:
        tasks = os.listdir("/proc/self/task")
    except OSError:
        return 1
    for task in tasks:
        try:
            with open(f"/proc/self/task/{task}/stat") as f:
                stat = f.read()
        except OSError:  # the thread ended while we looked
            continue
        count += stat[stat.rfind(")") + 2:][:1] == "R"  # the state follows "(name) "
    return max(count, 1)


def busy_cores(samples: int = 3) -> int:
    """How many cores other work keeps busy now: the machine's runnable tasks less this process's (its own threads,
    spinning torch workers among them, read before and after), the least over a few samples 10 ms apart (a task
    that is runnable only for an instant is not a busy core); 0 where the count cannot be read (not Linux)."""
    counts = []
    for i in range(samples):
        before = own_runnable_threads()
        machine = runnable_tasks()
        if machine is None:
            return 0
        counts.append(machine - max(before, own_runnable_threads()))
        if i + 1 < samples:
            time.sleep(0.01)
    return max(0, min(counts))


def free_threads(cores: int) -> int | None:
    """torch threads for `cores` cores beside the work now running: None (all of them) when none is busy, else the
    cores it leaves free, at least 1. One core: None without looking."""
    busy = busy_cores() if cores > 1 else 0
    return None if busy == 0 else max(1, cores - busy)


class _Share:
    """While a `shared_threads` block runs: the cores it may use and when it last looked at the machine."""

    def __init__(self, cores: int) -> None:
        self.cores, self.checked = cores, time.monotonic()


_share: list[_Share | None] = []  # per shared_threads block, innermost last: None where its count was given


@contextmanager
def shared_threads(threads: int | None) -> Iterator[None]:
    """torch's threads set to `threads` inside the block (0: left as they are), the caller's count restored after,
    also when the block raises. None: the cores other work leaves free (`free_threads`), looked at again every
    `CHECK_EVERY_S` seconds while a fit runs (`adapt`), so a fit started on an idle machine gives a core back to a
    job started after it, and takes it again when that job ends."""
    before = torch.get_num_threads()
    adaptive = threads is None and before > 1
    if threads is None:
        threads = free_threads(before)
    if threads:
        torch.set_num_threads(threads)
    _share.append(_Share(before) if adaptive else None)
    try:
        yield
    finally:
        _share.pop()
        torch.set_num_threads(before)


def adapt() -> str | None:
    """Inside a `shared_threads(None)` block, every `CHECK_EVERY_S` seconds: torch's threads set to the cores other
    work leaves free now (all when none is busy); a line saying so when the count changed, else None. Called by the
    trainer between steps (torch's thread count is per calling thread: only the one that runs the ops may set it)."""
    share = _share[-1] if _share else None
    if share is None:
        return None
    now = time.monotonic()
    if now - share.checked < CHECK_EVERY_S:
        return None
    share.checked = now
    busy = busy_cores()
    threads = max(1, share.cores - busy)
    if threads == torch.get_num_threads():
        return None
    torch.set_num_threads(threads)
    return (f"{threads} torch thread(s) from here: other work keeps {busy} of the {share.cores} cores busy" if busy
            else f"{threads} torch threads from here: the other work ended")
