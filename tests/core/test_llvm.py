"""Finding an LLVM that Mitsuba 3's LLVM backend compiles with, and refusing cleanly when there is none."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from neumat.core.errors import InputError
from neumat.core import llvm

LLVM15 = Path("/usr/lib/x86_64-linux-gnu/libLLVM-15.so.1")
SRC = str(Path(__file__).resolve().parents[2] / "src")


def _fake_libs(folder: Path, names: list[str]) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    for name in names:
        (folder / name).write_bytes(b"")


def test_version_from_file_names(tmp_path):
    assert [llvm.llvm_version(n) for n in ("libLLVM.so.19.1", "libLLVM-19.so", "libLLVM-14.0.6.so.1",
                                            "libLLVM-15.so.1", "libLLVM.so.20.1git", "libLLVM.so")] == \
        [19, 19, 14, 15, 20, None]
    (tmp_path / "libLLVM.so.18.1").write_bytes(b"")
    (tmp_path / "libLLVM.so").symlink_to(tmp_path / "libLLVM.so.18.1")
    assert llvm.llvm_version(tmp_path / "libLLVM.so") == 18  # read through the symlink


def test_find_keeps_llvm_16_and_newer_newest_first_once_per_file(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    _fake_libs(a, ["libLLVM-14.0.6.so.1", "libLLVM-15.so.1", "libLLVM.so.19.1", "libLLVMfoo.a"])
    (a / "libLLVM-19.so").symlink_to(a / "libLLVM.so.19.1")  # Debian's alias of the same file
    _fake_libs(b, ["libLLVM.so.20.1", "libLLVM-16.so"])
    found = llvm.find_libllvm([a, b, tmp_path / "missing"])
    assert [llvm.llvm_version(p) for p in found] == [20, 19, 16]


def test_library_dirs_start_with_ld_library_path(tmp_path, monkeypatch):
    monkeypatch.setenv("LD_LIBRARY_PATH", f"{tmp_path / 'x'}{os.pathsep}{tmp_path / 'y'}")
    assert llvm.library_dirs()[:2] == [tmp_path / "x", tmp_path / "y"]


def test_choice_and_refusal(monkeypatch, tmp_path):
    """The first candidate that passes the probe is chosen; a set DRJIT_LIBLLVM_PATH is probed, never
    overridden; none passing raises InputError naming the fix."""
    monkeypatch.setattr(llvm, "find_libllvm", lambda dirs=None: [Path("/l/libLLVM.so.20.1"), Path("/l/libLLVM-19.so")])
    for passing, expected in (({"/l/libLLVM-19.so"}, "/l/libLLVM-19.so"), ({None}, None)):
        monkeypatch.setattr(llvm, "probe", lambda lib, p=passing: (str(lib) if lib else None) in p and (True, "3.9")
                            or (False, "killed by signal 6: LLVM ERROR: Cannot select"))
        monkeypatch.delenv("DRJIT_LIBLLVM_PATH", raising=False)
        llvm.usable_libllvm.cache_clear()
        assert llvm.usable_libllvm() == expected
    monkeypatch.setattr(llvm, "probe", lambda lib: (False, "killed by signal 6: LLVM ERROR: Cannot select"))
    llvm.usable_libllvm.cache_clear()
    with pytest.raises(InputError, match="apt install libllvm19.*DRJIT_LIBLLVM_PATH"):
        llvm.usable_libllvm()
    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", "/l/libLLVM-15.so.1")
    llvm.usable_libllvm.cache_clear()
    with pytest.raises(InputError, match=r"DRJIT_LIBLLVM_PATH='/l/libLLVM-15.so.1' \(LLVM 15\).*apt install"):
        llvm.usable_libllvm()
    llvm.usable_libllvm.cache_clear()


@pytest.mark.skipif(not LLVM15.is_file(), reason=f"{LLVM15} (Debian 12's LLVM) is absent")
def test_llvm15_fails_the_probe_without_harming_the_caller():
    pytest.importorskip("mitsuba")
    ok, why = llvm.probe(LLVM15)
    assert not ok and "signal" in why and "LLVM ERROR" in why


@pytest.mark.skipif(not LLVM15.is_file(), reason=f"{LLVM15} (Debian 12's LLVM) is absent")
def test_cli_refuses_llvm15_with_the_fix(tmp_path):
    """Mitsuba 3 on LLVM 15 used to abort the process (SIGABRT) at its first kernel."""
    pytest.importorskip("mitsuba")
    mesh = tmp_path / "tri.ply"
    mesh.write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                    "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
                    "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n")
    env = {**os.environ, "PYTHONPATH": SRC, "DRJIT_LIBLLVM_PATH": str(LLVM15)}
    r = subprocess.run([sys.executable, "-m", "neumat.cli.main", "render", "ggx", "--scene", f"mesh:{mesh}",
                        "--resolution", "8", "-o", str(tmp_path / "x.png")],
                       env=env, capture_output=True, text=True, timeout=120)
    said = " ".join(r.stderr.split())
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr and "apt install libllvm19" in said and "LLVM 15" in said
    assert not (tmp_path / "x.png").exists()
