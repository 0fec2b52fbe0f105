"""Detect a usable Mitsuba 3 (LLVM backend) without risking the test process, and import it.

A broken LLVM can abort the interpreter at its first kernel, so `neumat.core.llvm` probes each
candidate library in a subprocess. Use `mitsuba_or_skip()` inside a test (it skips with the reason, which
names the fix) and mark the test `@pytest.mark.mitsuba`.
"""
from __future__ import annotations

import functools

import pytest

from neumat.core.errors import InputError
from neumat.core.llvm import VARIANT, configure_llvm


@functools.lru_cache(maxsize=1)
def mitsuba_status() -> tuple[bool, str]:
    """(usable, reason), probed once per session; sets DRJIT_LIBLLVM_PATH to the usable LLVM."""
    try:
        import mitsuba  # noqa: F401
    except ImportError as e:
        return False, f"Mitsuba 3 is not installed: {e}"
    try:
        configure_llvm()
    except InputError as e:
        return False, str(e)
    return True, ""


def mitsuba_or_skip():
    """The `mitsuba` module with variant VARIANT set, or skip the calling test with the reason."""
    ok, reason = mitsuba_status()
    if not ok:
        pytest.skip(reason)
    import mitsuba as mi
    mi.set_variant(VARIANT)
    return mi
