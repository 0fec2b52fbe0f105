"""The default torch threads of a command: the cores other work leaves free (`neumat.cli.common.free_threads`)."""
from __future__ import annotations

import subprocess
import sys
import time

import pytest
import torch

from neumat.cli import common


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc/loadavg (Linux)")
def test_a_busy_process_is_counted():
    spinner = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    try:
        time.sleep(0.3)
        assert common.busy_cores() >= 1
    finally:
        spinner.kill()
        spinner.wait()


@pytest.mark.parametrize("busy, cores, threads", [(0, 2, None), (1, 2, 1), (5, 2, 1), (1, 8, 7), (3, 8, 5), (1, 1, None)])
def test_free_threads_leaves_the_busy_cores_and_keeps_one(monkeypatch, busy, cores, threads):
    monkeypatch.setattr(common, "busy_cores", lambda: busy)
    assert common.free_threads(cores) == threads


def test_a_command_without_threads_runs_on_the_free_cores_and_restores_the_count(monkeypatch):
    """torch_threads(None) beside one busy process of 2 cores: 1 thread inside, 2 again after (also after an
    error); an explicit count wins; beside no busy process torch's count stays."""
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        monkeypatch.setattr(common, "busy_cores", lambda: 1)
        with common.torch_threads(None):
            assert torch.get_num_threads() == 1
        with pytest.raises(ZeroDivisionError), common.torch_threads(None):
            1 / 0
        assert torch.get_num_threads() == 2
        with common.torch_threads(2):
            assert torch.get_num_threads() == 2
        monkeypatch.setattr(common, "busy_cores", lambda: 0)
        with common.torch_threads(None):
            assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(before)
