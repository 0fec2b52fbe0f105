"""Detect a usable Mitsuba 3 (LLVM backend) without risking the test process, and import it.

A broken LLVM can abort the interpreter at its first kernel, so `neumat.core.llvm` probes each
candidate library in a subprocess, once per process. Use `mitsuba_or_skip()` inside a test (it skips with the
reason, which names the fix) and mark the test `@pytest.mark.mitsuba`.
"""
from __future__ import annotations

import pytest

from neumat.core.errors import InputError
from neumat.core.mitsuba import import_mitsuba


def mitsuba_or_skip():
    """The `mitsuba` module with variant llvm_ad_rgb set, or skip the calling test with the reason."""
    try:
        return import_mitsuba()
    except InputError as e:
        pytest.skip(str(e))
