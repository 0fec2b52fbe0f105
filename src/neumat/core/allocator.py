"""Freed memory kept in the process for reuse: by default glibc's malloc serves every block of 32 MB or more from
a fresh mapping and gives it back to the kernel when freed (and trims the heap's top above 128 KB), so a fit whose
steps allocate large temporaries (a 1K latent texture's gradient, a batch of translucent observations) pays a page
fault for every 4 KB of them at every step: 38 % of a 1K texture set fit's CPU and 29 % of a NeuPreSS fit's went to
the kernel (docs/notes/fit.md, "neumat.core.allocator")."""
from __future__ import annotations

import ctypes
import sys

#: mallopt parameters (glibc's malloc.h)
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3
#: blocks up to this size come from the heap, and this much free heap top is kept (a process's peak memory, not
#: more, stays mapped)
RETAINED_BYTES = 1 << 30
_retaining: list[bool] = []


def retain_freed_memory() -> bool:
    """Have glibc's malloc keep freed blocks of up to RETAINED_BYTES for reuse instead of unmapping them; once per
    process (later calls return the first answer). True where it took effect; False where the C library has no
    `mallopt` or refuses (not glibc: nothing changes)."""
    if not _retaining:
        _retaining.append(_set_thresholds())
    return _retaining[0]


def _set_thresholds() -> bool:
    if not sys.platform.startswith("linux"):
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    # the mmap threshold first: setting either fixes the other's dynamic adjustment at its current value
    return mallopt(_M_MMAP_THRESHOLD, RETAINED_BYTES) == 1 and mallopt(_M_TRIM_THRESHOLD, RETAINED_BYTES) == 1
