"""Find an LLVM library that Mitsuba 3's LLVM backend (Dr.Jit) can compile with, before Mitsuba loads one.

Dr.Jit emits intrinsics (`llvm.maximum`, `llvm.minimum`) that LLVM 15 cannot select: on such an LLVM the
first kernel using them aborts the process ("LLVM ERROR: Cannot select ... fmaximum"), which no Python
`except` catches, and a probe such as `mi.Float * 2` passes. So each candidate library is probed in a
subprocess with a real kernel (a ray cast, `dr.maximum`, `dr.minimum`), and the resolved file of the first
that passes is put in DRJIT_LIBLLVM_PATH for this process. Dr.Jit reads that variable once, when `drjit` is
imported, so nothing may import it before `configure_llvm()`.

Candidates: DRJIT_LIBLLVM_PATH when it is set (the only one then: the user's choice is probed, not
overridden, and refused unprobed when its name says LLVM < 16); else every versioned `libLLVM*.so*` of version
>= 16 in the search folders, newest first. The folders are $NEUMAT_LIBLLVM_DIRS when set (an os.pathsep list;
CI points it at an empty folder to act out a machine without LLVM >= 16), else LD_LIBRARY_PATH, the system
library folders and /usr/lib/llvm-*/lib. None passing raises InputError naming the fix. The answer, either
way, is decided once per process: a library installed while the process runs does not change it.
"""
from __future__ import annotations

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
    """Folders searched for libLLVM: $NEUMAT_LIBLLVM_DIRS when set, else LD_LIBRARY_PATH, the system library
    folders and /usr/lib/llvm-*/lib."""
    chosen = os.environ.get("NEUMAT_LIBLLVM_DIRS")
    if chosen is not None:
        return [Path(d) for d in chosen.split(os.pathsep) if d]
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


def probe(libllvm: str | Path, timeout: float = _PROBE_TIMEOUT_S) -> tuple[bool, str]:
    """Run a Mitsuba kernel in a subprocess with DRJIT_LIBLLVM_PATH = `libllvm`.
    Returns (passed, Mitsuba's version or why it failed)."""
    env = {**os.environ, "DRJIT_LIBLLVM_PATH": str(libllvm)}
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


def choose_libllvm() -> str:
    """Probe the candidates (module docstring) now; the resolved path of the first that passes. Raises
    InputError naming the fix when none does."""
    given = os.environ.get("DRJIT_LIBLLVM_PATH")
    if given:
        v = llvm_version(given)
        label = f"DRJIT_LIBLLVM_PATH={given!r}{f' (LLVM {v})' if v else ''}"
        if v is not None and v < MIN_LLVM:
            raise InputError(f"{label} is older than the LLVM {MIN_LLVM} Mitsuba 3's LLVM backend needs; {FIX}")
        real = os.path.realpath(given)
        if not os.path.isfile(real):
            raise InputError(f"{label} is not a file; {FIX}")
        ok, why = probe(real)
        if ok:
            return real
        raise InputError(f"{label} is unusable by Mitsuba 3's LLVM backend ({why}); {FIX}")
    tried = []
    for lib in find_libllvm():
        real = os.path.realpath(lib)
        ok, why = probe(real)
        if ok:
            return real
        tried.append(f"{lib}: {why}")
    where = ("$NEUMAT_LIBLLVM_DIRS=" + os.environ["NEUMAT_LIBLLVM_DIRS"] if "NEUMAT_LIBLLVM_DIRS" in os.environ
             else "the library folders")
    raise InputError(f"Mitsuba 3's LLVM backend found no usable LLVM >= {MIN_LLVM} "
                     f"({'; '.join(tried) if tried else 'none in ' + where}); {FIX}")


#: (library, None) or (None, refusal) once `usable_libllvm` has decided for this process
_decided: tuple[str | None, str | None] | None = None


def usable_libllvm() -> str:
    """The resolved path of the library that passed the probe, decided once per process (`choose_libllvm`):
    a later call, also after a refusal, gives the same answer without probing again."""
    global _decided
    if _decided is None:
        try:
            _decided = (choose_libllvm(), None)
        except InputError as e:
            _decided = (None, str(e))
    lib, refusal = _decided
    if refusal is not None:
        raise InputError(refusal)
    return lib


def loaded_libllvms() -> set[str]:
    """The resolved paths of the libLLVMs this process has mapped (Linux's /proc/self/maps; Mesa's llvmpipe maps
    one too), or an empty set."""
    try:
        maps = Path("/proc/self/maps").read_text()
    except OSError:
        return set()
    return {os.path.realpath(fields[5]) for fields in (line.split(maxsplit=5) for line in maps.splitlines())
            if len(fields) == 6 and Path(fields[5]).name.startswith("libLLVM")}


def configure_llvm() -> None:
    """Point DRJIT_LIBLLVM_PATH at the library `usable_libllvm()` chose, or raise InputError. Also an
    InputError when Dr.Jit, imported earlier, loaded another libLLVM instead: its kernels could abort."""
    lib = usable_libllvm()
    loaded = loaded_libllvms() if "drjit" in sys.modules else set()
    if loaded and lib not in loaded:
        raise InputError(f"Dr.Jit was imported before neumat chose an LLVM and loaded {', '.join(sorted(loaded))}, "
                         f"not {lib} (which passed the probe); let neumat load Mitsuba first "
                         "(neumat.core.mitsuba.import_mitsuba) or set DRJIT_LIBLLVM_PATH before importing drjit")
    os.environ["DRJIT_LIBLLVM_PATH"] = lib
