"""Find an LLVM library that Mitsuba 3's LLVM backend (Dr.Jit) can compile with, before Mitsuba loads one.

Dr.Jit emits intrinsics (`llvm.maximum`, `llvm.minimum`) that LLVM 15 cannot select: on such an LLVM the
first kernel using them aborts the process ("LLVM ERROR: Cannot select ... fmaximum"), which no Python
`except` catches, and a probe such as `mi.Float * 2` passes. So each candidate library is probed in a
subprocess with a real kernel (a ray cast, `dr.maximum`, `dr.minimum`), and the first that passes is put in
DRJIT_LIBLLVM_PATH for this process.

Candidates, in order: DRJIT_LIBLLVM_PATH when it is set (the only one then: the user's choice is probed, not
overridden); else every versioned `libLLVM*.so*` of version >= 16 in the library path (LD_LIBRARY_PATH, the
system library folders, /usr/lib/llvm-*/lib), newest first; else Dr.Jit's own search. None passing raises
InputError naming the fix.
"""
from __future__ import annotations

import functools
import os
import re
import secrets
import subprocess
import sys
from pathlib import Path

from .errors import InputError

#: the oldest LLVM major version Dr.Jit's kernels compile with
MIN_LLVM = 16
#: Mitsuba variant the probe loads
VARIANT = "llvm_ad_rgb"
FIX = ("install LLVM >= 16 (`apt install libllvm19`) or set DRJIT_LIBLLVM_PATH to the path of a libLLVM "
       f"of version >= {MIN_LLVM}")
_SYSTEM_DIRS = ("/usr/lib/x86_64-linux-gnu", "/usr/lib/aarch64-linux-gnu", "/lib/x86_64-linux-gnu",
                "/usr/lib64", "/usr/lib", "/usr/local/lib", "/opt/homebrew/opt/llvm/lib", "/usr/local/opt/llvm/lib")
_VERSION = re.compile(r"libLLVM(?:-|\.so\.|\.)(\d+)")
_PROBE_TIMEOUT_S = 120
# A literal drawn per probe makes the kernel new, so Dr.Jit's on-disk kernel cache cannot answer for LLVM.
_PROBE = """
import drjit as dr, mitsuba as mi
mi.set_variant({variant!r})
scene = mi.load_dict({{"type": "scene", "s": {{"type": "sphere"}}}})
ray = mi.Ray3f(mi.Point3f([0.0, 0.5, 3.0], 0.0, 5.0), mi.Vector3f(0.0, 0.0, -1.0))
si = scene.ray_intersect(ray)
v = dr.maximum(si.t, {c}) + dr.minimum(si.t, {c})
assert list(si.is_valid()) == [True, True, False], list(si.is_valid())
dr.eval(v)
print(mi.__version__)
"""


def llvm_version(path: str | Path) -> int | None:
    """The LLVM major version in a library's file name (following symlinks), or None when it names none."""
    for name in (Path(path).name, Path(os.path.realpath(path)).name):
        m = _VERSION.match(name)
        if m:
            return int(m.group(1))
    return None


def library_dirs() -> list[Path]:
    """Folders searched for libLLVM: LD_LIBRARY_PATH, the system library folders, /usr/lib/llvm-*/lib."""
    dirs = [Path(d) for d in os.environ.get("LD_LIBRARY_PATH", "").split(os.pathsep) if d]
    dirs += [Path(d) for d in _SYSTEM_DIRS]
    dirs += sorted(Path("/usr/lib").glob("llvm-*/lib"))
    return list(dict.fromkeys(dirs))


def find_libllvm(dirs: list[Path] | None = None) -> list[Path]:
    """Versioned `libLLVM*.so*` files of version >= MIN_LLVM in `dirs` (default `library_dirs()`), newest
    first, one per resolved file."""
    found: dict[str, tuple[int, Path]] = {}
    for d in library_dirs() if dirs is None else dirs:
        try:
            names = sorted(d.glob("libLLVM*.so*"))
        except OSError:
            continue
        for p in names:
            v = llvm_version(p)
            real = os.path.realpath(p)
            if v is not None and v >= MIN_LLVM and real not in found and os.path.isfile(real):
                found[real] = (v, p)
    return [p for v, p in sorted(found.values(), key=lambda vp: -vp[0])]


def probe(libllvm: str | Path | None, timeout: float = _PROBE_TIMEOUT_S) -> tuple[bool, str]:
    """Run a Mitsuba kernel in a subprocess with DRJIT_LIBLLVM_PATH = `libllvm` (None: Dr.Jit's own search).
    Returns (passed, Mitsuba's version or why it failed)."""
    env = dict(os.environ)
    env.pop("DRJIT_LIBLLVM_PATH", None)
    if libllvm is not None:
        env["DRJIT_LIBLLVM_PATH"] = str(libllvm)
    code = _PROBE.format(variant=VARIANT, c=0.25 + secrets.randbelow(1 << 20) / (1 << 22))
    try:
        r = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return False, f"the probe timed out after {timeout:g} s"
    if r.returncode == 0:
        return True, r.stdout.strip()
    lines = [ln for ln in (r.stderr or r.stdout).strip().splitlines() if ln.strip()]
    why = next((ln for ln in lines if "LLVM ERROR" in ln), lines[-1] if lines else "")
    how = f"killed by signal {-r.returncode}" if r.returncode < 0 else f"exit code {r.returncode}"
    return False, f"{how}: {why[:200]}" if why else how


@functools.lru_cache(maxsize=1)
def usable_libllvm() -> str | None:
    """The library path that passed the probe (None: Dr.Jit's own search passed), probed once per process.
    Raises InputError naming the fix when no candidate passes."""
    given = os.environ.get("DRJIT_LIBLLVM_PATH")
    if given:
        ok, why = probe(given)
        if ok:
            return given
        v = llvm_version(given)
        raise InputError(f"DRJIT_LIBLLVM_PATH={given!r}{f' (LLVM {v})' if v else ''} is unusable by Mitsuba 3's "
                         f"LLVM backend ({why}); {FIX}")
    tried = []
    for lib in find_libllvm():
        ok, why = probe(lib)
        if ok:
            return str(lib)
        tried.append(f"{lib}: {why}")
    ok, why = probe(None)
    if ok:
        return None
    tried.append(f"Dr.Jit's own search: {why}")
    raise InputError(f"Mitsuba 3's LLVM backend found no usable LLVM >= {MIN_LLVM} ({'; '.join(tried)}); {FIX}")


def configure_llvm() -> None:
    """Point DRJIT_LIBLLVM_PATH at a usable LLVM (see the module docstring) or raise InputError.
    Call before Mitsuba loads its LLVM backend."""
    lib = usable_libllvm()
    if lib is not None:
        os.environ["DRJIT_LIBLLVM_PATH"] = lib
