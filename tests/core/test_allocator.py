"""neumat.core.allocator: freed large blocks are reused, not faulted in afresh (measured in fresh processes: one
with the setting, one with glibc's default)."""
import subprocess
import sys

import pytest

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt: Linux only")

#: minor page faults of 20 cycles of allocating, touching and freeing a 64 MB tensor (16,384 pages a cycle), after 10
#: such cycles (while they run the retained heap grows to fit the next block's alignment; then it is reused)
_CYCLES = """
import resource, sys, torch
from neumat.core.allocator import retain_freed_memory
took = retain_freed_memory() if sys.argv[1] == "retain" else None
for _ in range(10):
    torch.empty(16 << 20).fill_(1.0)
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(20):
    torch.empty(16 << 20).fill_(1.0)
print(took, resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


def _faults(mode: str) -> tuple[str, int]:
    out = subprocess.run([sys.executable, "-c", _CYCLES, mode], capture_output=True, text=True, check=True)
    took, faults = out.stdout.split()
    return took, int(faults)


def test_retained_blocks_are_reused_without_page_faults():
    took, retained = _faults("retain")
    if took != "True":
        pytest.skip("this C library has no glibc mallopt (musl, ...): retain_freed_memory changes nothing")
    _, default = _faults("default")
    assert default > 20 * 16384 * 0.9, f"glibc's default should fault every cycle in afresh ({default} faults)"
    assert retained < 16384, f"freed 64 MB blocks faulted in again: {retained} minor faults over 20 cycles"
