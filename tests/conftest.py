"""Shared fixtures: the real-data folder, seeded generators, one torch thread per test process."""
from __future__ import annotations

from pathlib import Path

import pytest
import torch

from neumat.io.shared_data import shared_data_candidates, shared_data_dir

#: the library's answer ($NEUMAT_SHARED_DATA, else ../shared/data), so tests and commands read the same data
SHARED_DATA = shared_data_dir()

# one torch thread per test process: xdist runs one process per core, and small test batches gain
# nothing from intra-op threads while oversubscribed cores slow them down many times over
torch.set_num_threads(1)


@pytest.fixture
def shared_data() -> Path:
    """The reference data folder (`neumat.io.shared_data`); skips the test when it is absent."""
    if SHARED_DATA is None:
        pytest.skip(f"real data folder absent (looked in {', '.join(map(str, shared_data_candidates()))}; set "
                    "NEUMAT_SHARED_DATA)")
    return SHARED_DATA


@pytest.fixture
def without_llvm(monkeypatch):
    """This process has decided that no LLVM >= 16 is usable, as on a fresh Debian 12: whatever reaches Mitsuba
    refuses, so a command's own argument errors show only when it checks them first."""
    from neumat.core import llvm
    monkeypatch.setattr(llvm, "_decided", (None, "Mitsuba 3's LLVM backend found no usable LLVM >= 16 (test); "
                                                 + llvm.FIX))


@pytest.fixture
def gen() -> torch.Generator:
    """A seeded CPU generator."""
    return torch.Generator().manual_seed(1234)


def pytest_collection_modifyitems(config, items):
    """Skip tests marked `cuda` when torch sees no CUDA GPU (the marker, not the keyword: a parameter named "cuda",
    such as the cuda benchmark suite's quick run, is no GPU test)."""
    if torch.cuda.is_available():
        return
    skip = pytest.mark.skip(reason="needs a CUDA GPU (torch.cuda.is_available() is False)")
    for item in items:
        if item.get_closest_marker("cuda") is not None:
            item.add_marker(skip)


def pytest_terminal_summary(terminalreporter):
    """One line per distinct skip reason with its count, so that `make test -q` says why tests skipped (Mitsuba
    without LLVM >= 16, no GPU, no shared data) without pytest's per-location -rs list."""
    reasons: dict[str, int] = {}
    for report in terminalreporter.stats.get("skipped", []):
        if isinstance(report.longrepr, tuple):
            reason = report.longrepr[2].removeprefix("Skipped: ")
            reasons[reason] = reasons.get(reason, 0) + 1
    for reason, count in sorted(reasons.items(), key=lambda rc: -rc[1]):
        terminalreporter.write_line(f"skipped {count}: {reason}")
