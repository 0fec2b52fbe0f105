"""Detect a usable Mitsuba 3 (LLVM backend) without risking the test process, and import it.

A broken LLVM can crash the interpreter inside `mi.set_variant`, so the first check runs in a
subprocess. Use `mitsuba_or_skip()` inside a test (it skips with the reason) and mark the test
`@pytest.mark.mitsuba`.
"""
from __future__ import annotations

import functools
import os
import subprocess
import sys
from pathlib import Path

import pytest

VARIANT = "llvm_ad_rgb"
LIBLLVM = Path("/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1")

_PROBE = (
    "import mitsuba as mi\n"
    f"mi.set_variant('{VARIANT}')\n"
    "x = mi.Float([1.0, 2.0]) * 2\n"
    "assert list(x) == [2.0, 4.0]\n"
    "print(mi.__version__)\n"
)


def mitsuba_env() -> dict:
    """Environment for Mitsuba: DRJIT_LIBLLVM_PATH set to LIBLLVM when that file exists and none is set."""
    env = dict(os.environ)
    if "DRJIT_LIBLLVM_PATH" not in env and LIBLLVM.is_file():
        env["DRJIT_LIBLLVM_PATH"] = str(LIBLLVM)
    return env


@functools.lru_cache(maxsize=1)
def mitsuba_status() -> tuple[bool, str]:
    """(usable, reason or version), probed once per session in a subprocess."""
    try:
        r = subprocess.run([sys.executable, "-c", _PROBE], env=mitsuba_env(), capture_output=True,
                           text=True, timeout=120)
    except subprocess.TimeoutExpired:
        return False, f"Mitsuba probe ({VARIANT}) timed out"
    if r.returncode != 0:
        tail = (r.stderr or r.stdout).strip().splitlines()[-1:] or [f"exit code {r.returncode}"]
        return False, f"Mitsuba {VARIANT} unavailable: {tail[0]}"
    return True, r.stdout.strip()


def mitsuba_or_skip():
    """The `mitsuba` module with variant VARIANT set, or skip the calling test with the reason."""
    ok, reason = mitsuba_status()
    if not ok:
        pytest.skip(reason)
    for k, v in mitsuba_env().items():
        os.environ.setdefault(k, v)
    import mitsuba as mi
    mi.set_variant(VARIANT)
    return mi
