"""torch's threads beside other work (`neumat.core.threads`): busy cores counted without this process's own threads,
the free cores taken when a command starts, and given back or taken again while a fit runs."""
from __future__ import annotations

import subprocess
import sys
import threading
import time

import pytest
import torch

from neumat.core import threads

linux = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc (Linux)")


@pytest.fixture
def two_threads():
    """torch on 2 threads for the test (the suite runs on 1: conftest), the count restored after."""
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    yield
    torch.set_num_threads(before)


@linux
def test_a_busy_process_is_counted():
    spinner = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    try:
        time.sleep(0.3)
        assert threads.busy_cores() >= 1
    finally:
        spinner.kill()
        spinner.wait()


@linux
def test_this_process_threads_running_ops_are_its_own_and_not_other_work(monkeypatch):
    """A thread of this process inside a torch op (the GIL released) is runnable and counted as this process's, so
    a fit's own spinning workers are never taken for other work; busy = machine less own."""
    stop = threading.Event()

    def work():
        a = torch.randn(256, 256)
        while not stop.is_set():
            a @ a
    worker = threading.Thread(target=work)
    worker.start()
    try:
        time.sleep(0.05)
        assert max(threads.own_runnable_threads() for _ in range(50)) >= 2
    finally:
        stop.set()
        worker.join()
    assert threads.own_runnable_threads() >= 1
    monkeypatch.setattr(threads, "own_runnable_threads", lambda: 2)
    for machine, busy in ((2, 0), (3, 1), (1, 0), (None, 0)):
        monkeypatch.setattr(threads, "runnable_tasks", lambda machine=machine: machine)
        assert threads.busy_cores() == busy, machine


@pytest.mark.parametrize("busy, cores, count", [(0, 2, None), (1, 2, 1), (5, 2, 1), (1, 8, 7), (3, 8, 5), (1, 1, None)])
def test_free_threads_leaves_the_busy_cores_and_keeps_one(monkeypatch, busy, cores, count):
    monkeypatch.setattr(threads, "busy_cores", lambda: busy)
    assert threads.free_threads(cores) == count


def test_a_block_without_threads_runs_on_the_free_cores_and_restores_the_count(monkeypatch, two_threads):
    """shared_threads(None) beside one busy process of 2 cores: 1 thread inside, 2 again after (also after an
    error); an explicit count wins; beside no busy process torch's count stays."""
    monkeypatch.setattr(threads, "busy_cores", lambda: 1)
    with threads.shared_threads(None):
        assert torch.get_num_threads() == 1
    with pytest.raises(ZeroDivisionError), threads.shared_threads(None):
        1 / 0
    assert torch.get_num_threads() == 2
    with threads.shared_threads(2):
        assert torch.get_num_threads() == 2
    monkeypatch.setattr(threads, "busy_cores", lambda: 0)
    with threads.shared_threads(None):
        assert torch.get_num_threads() == 2


def test_adapt_gives_a_core_back_to_later_work_and_takes_it_again(monkeypatch, two_threads):
    """Inside shared_threads(None) on an idle machine: another job starts (1 core busy) -> 1 thread and a line
    saying so; unchanged -> nothing; it ends -> 2 threads again. Not before CHECK_EVERY_S, not under an explicit
    count, not outside a block."""
    busy = [0]
    monkeypatch.setattr(threads, "busy_cores", lambda: busy[0])
    with threads.shared_threads(None):
        assert torch.get_num_threads() == 2
        busy[0] = 1
        assert threads.adapt() is None  # CHECK_EVERY_S has not passed
        monkeypatch.setattr(threads, "CHECK_EVERY_S", 0.0)
        assert "1 of the 2 cores busy" in threads.adapt() and torch.get_num_threads() == 1
        assert threads.adapt() is None and torch.get_num_threads() == 1
        busy[0] = 0
        assert "ended" in threads.adapt() and torch.get_num_threads() == 2
        busy[0] = 1
        with threads.shared_threads(2):  # an explicit count is kept
            assert threads.adapt() is None and torch.get_num_threads() == 2
    assert threads.adapt() is None and torch.get_num_threads() == 2


@pytest.mark.filterwarnings("ignore:.*learned none of the source:UserWarning")  # 4 steps learn nothing
def test_a_fit_gives_up_a_thread_when_other_work_starts_and_says_so(monkeypatch, two_threads, capsys):
    """The trainer adapts between steps: a fit under shared_threads(None) runs its later steps on 1 thread once
    another job keeps a core busy, with a line on stderr (progress on), and the caller's 2 threads come back."""
    from neumat.fit.recipe import Recipe
    from neumat.fit.trainer import fit
    from neumat.methods.neubrdf.model import NeuBRDF
    from tests.fit.test_trainer import Blinn

    busy = [0]
    monkeypatch.setattr(threads, "busy_cores", lambda: busy[0])
    monkeypatch.setattr(threads, "CHECK_EVERY_S", 0.0)
    seen = []

    def record(_):
        seen.append(torch.get_num_threads())
        busy[0] = 1  # another job starts after the first record

    m = NeuBRDF(nside=2, index_bits=3, hidden=4, features="dense", direction_inputs="hd_warp")
    with threads.shared_threads(None):
        fit(m, Blinn(), Recipe(steps=4, lr=1e-3, batch_size=16, log_every=1), steps=4, progress=True,
            callback=record)
    assert seen == [2, 1, 1, 1] and torch.get_num_threads() == 2
    assert "1 torch thread(s) from here: other work keeps 1 of the 2 cores busy" in capsys.readouterr().err
