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


def test_search_folders_can_be_named(tmp_path, monkeypatch):
    """$NEUMAT_LIBLLVM_DIRS replaces the default folders (CI names an empty one to act out a machine without
    LLVM >= 16)."""
    monkeypatch.setenv("NEUMAT_LIBLLVM_DIRS", f"{tmp_path / 'x'}{os.pathsep}{tmp_path / 'y'}")
    assert llvm.library_dirs() == [tmp_path / "x", tmp_path / "y"]


def _probe_passing(monkeypatch, passing: set[str]) -> list[str]:
    """Replace the probe by one that passes exactly the paths in `passing`; returns the list of probed paths."""
    probed = []

    def probe(lib):
        probed.append(str(lib))
        return (True, "3.9") if str(lib) in passing else (False, "killed by signal 6: LLVM ERROR: Cannot select")
    monkeypatch.setattr(llvm, "probe", probe)
    return probed


def test_choice_and_refusal(monkeypatch, tmp_path):
    """The resolved file of the first candidate that passes is chosen; a set DRJIT_LIBLLVM_PATH is the only
    candidate, refused unprobed when its name says LLVM < 16; none passing raises InputError naming the fix."""
    _fake_libs(tmp_path, ["libLLVM.so.20.1", "libLLVM.so.19.1", "libLLVM-15.so.1"])
    (tmp_path / "libLLVM-19.so").symlink_to(tmp_path / "libLLVM.so.19.1")
    monkeypatch.setenv("NEUMAT_LIBLLVM_DIRS", str(tmp_path))
    monkeypatch.delenv("DRJIT_LIBLLVM_PATH", raising=False)
    nineteen = str(tmp_path / "libLLVM.so.19.1")
    probed = _probe_passing(monkeypatch, {nineteen})
    assert llvm.choose_libllvm() == nineteen
    assert probed == [str(tmp_path / "libLLVM.so.20.1"), nineteen]  # resolved files, newest first, never 15
    _probe_passing(monkeypatch, set())
    with pytest.raises(InputError, match="libLLVM.so.20.1: killed by signal 6.*apt install libllvm19.*DRJIT_LIBLL"):
        llvm.choose_libllvm()
    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", str(tmp_path / "libLLVM-19.so"))
    probed = _probe_passing(monkeypatch, {nineteen})
    assert llvm.choose_libllvm() == nineteen and probed == [nineteen]  # the symlink's file, not the link
    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", str(tmp_path / "libLLVM-15.so.1"))
    with pytest.raises(InputError, match=r"DRJIT_LIBLLVM_PATH='.*libLLVM-15.so.1' \(LLVM 15\) is older.*apt install"):
        llvm.choose_libllvm()
    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", str(tmp_path / "missing" / "libLLVM.so.19.1"))
    with pytest.raises(InputError, match=r"\(LLVM 19\) is not a file.*apt install libllvm19"):
        llvm.choose_libllvm()
    assert probed == [nineteen]  # neither was probed


def test_empty_search_refuses_without_probing(monkeypatch, tmp_path):
    monkeypatch.setenv("NEUMAT_LIBLLVM_DIRS", str(tmp_path))
    monkeypatch.delenv("DRJIT_LIBLLVM_PATH", raising=False)
    probed = _probe_passing(monkeypatch, set())
    with pytest.raises(InputError, match=r"no usable LLVM >= 16 \(none in \$NEUMAT_LIBLLVM_DIRS=.*libllvm19"):
        llvm.choose_libllvm()
    assert probed == []


def test_the_answer_is_decided_once_per_process(monkeypatch, tmp_path):
    """A library appearing (or vanishing) while the process runs does not change the answer: no new probe."""
    monkeypatch.setenv("NEUMAT_LIBLLVM_DIRS", str(tmp_path))
    monkeypatch.delenv("DRJIT_LIBLLVM_PATH", raising=False)
    monkeypatch.setattr(llvm, "_decided", None)  # restored after the test: the session keeps its own answer
    nineteen = str(tmp_path / "libLLVM.so.19.1")
    probed = _probe_passing(monkeypatch, {nineteen})
    for _ in range(2):
        with pytest.raises(InputError, match="none in"):
            llvm.usable_libllvm()
    _fake_libs(tmp_path, ["libLLVM.so.19.1"])  # installed under the running process
    with pytest.raises(InputError, match="none in"):
        llvm.usable_libllvm()
    assert probed == []
    monkeypatch.setattr(llvm, "_decided", None)
    assert llvm.usable_libllvm() == nineteen and probed == [nineteen]
    (tmp_path / "libLLVM.so.19.1").unlink()
    assert llvm.usable_libllvm() == nineteen and probed == [nineteen]


def test_configure_points_drjit_at_the_chosen_file_or_refuses_another_loaded(monkeypatch):
    monkeypatch.setattr(llvm, "_decided", ("/l/libLLVM.so.19.1", None))
    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", "/l/libLLVM-19.so")
    monkeypatch.delitem(sys.modules, "drjit", raising=False)
    llvm.configure_llvm()
    assert os.environ["DRJIT_LIBLLVM_PATH"] == "/l/libLLVM.so.19.1"
    monkeypatch.setitem(sys.modules, "drjit", object())  # Dr.Jit imported earlier, with its own choice
    monkeypatch.setattr(llvm, "loaded_libllvms", lambda: {"/usr/lib/libLLVM-15.so.1"})
    with pytest.raises(InputError, match="loaded /usr/lib/libLLVM-15.so.1, not /l/libLLVM.so.19.1"):
        llvm.configure_llvm()
    # Mesa's llvmpipe (the GLSL tests) maps its LLVM beside Dr.Jit's
    monkeypatch.setattr(llvm, "loaded_libllvms", lambda: {"/usr/lib/libLLVM-15.so.1", "/l/libLLVM.so.19.1"})
    llvm.configure_llvm()


@pytest.mark.skipif(not LLVM15.is_file(), reason=f"{LLVM15} (Debian 12's LLVM) is absent")
def test_llvm15_fails_the_probe_without_harming_the_caller():
    pytest.importorskip("mitsuba")
    ok, why = llvm.probe(LLVM15)
    assert not ok and "signal" in why and "LLVM ERROR" in why


_TRIANGLE = ("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
             "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n")


@pytest.mark.parametrize("command,setting", [("render", "empty search"), ("mitsuba-render", "LLVM 15"),
                                             ("trace", "missing file")])
def test_cli_refuses_without_llvm_16_in_one_line_naming_libllvm19(tmp_path, command, setting):
    """A machine without LLVM >= 16: each Mitsuba command exits 2 with neumat's line only (no Dr.Jit line: Dr.Jit
    is never loaded) and writes nothing. Mitsuba 3 on LLVM 15 used to abort the process at its first kernel."""
    pytest.importorskip("mitsuba")
    (tmp_path / "tri.ply").write_text(_TRIANGLE)
    (tmp_path / "s.xml").write_text('<scene version="3.0.0"><shape type="sphere"/></scene>')
    empty = tmp_path / "empty"
    empty.mkdir()
    env = {k: v for k, v in os.environ.items() if k != "DRJIT_LIBLLVM_PATH"}
    env.update(PYTHONPATH=SRC, NEUMAT_LIBLLVM_DIRS=str(empty))
    if setting == "LLVM 15":
        env["DRJIT_LIBLLVM_PATH"] = str(LLVM15)  # refused by its name: need not exist
    elif setting == "missing file":
        env["DRJIT_LIBLLVM_PATH"] = str(tmp_path / "gone" / "libLLVM.so.19.1")  # Dr.Jit would complain about it
    args = {"render": ["render", "ggx", "--scene", f"mesh:{tmp_path / 'tri.ply'}", "--resolution", "8"],
            "mitsuba-render": ["mitsuba-render", str(tmp_path / "s.xml")],
            "trace": ["translucent", "trace", "--images", "1"]}[command]
    out = tmp_path / ("x.npz" if command == "trace" else "x.png")
    r = subprocess.run([sys.executable, "-m", "neumat.cli.main", *args, "-o", str(out)],
                       env=env, capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and r.stderr.startswith("error: "), r.stderr
    assert "apt install libllvm19" in r.stderr and {"empty search": "none in", "LLVM 15": "(LLVM 15) is older",
                                                    "missing file": "is not a file"}[setting] in r.stderr
    assert r.stdout == "" and sorted(p.name for p in tmp_path.iterdir()) == ["empty", "s.xml", "tri.ply"]


_VARIANT_WITHOUT_LLVM = """
from neumat.core.errors import InputError
from neumat.core.mitsuba import import_mitsuba
for variant in ("llvm_ad_rgb", "cuda_ad_rgb"):
    try:
        import_mitsuba(variant)
        print(variant, "loaded")
    except InputError as e:
        print(variant, "refused:", str(e).splitlines()[0])
"""


def test_a_cuda_variant_needs_no_llvm(tmp_path):
    """Without LLVM >= 16, import_mitsuba refuses an LLVM variant naming the fix, and goes on to load a CUDA variant
    (which on a machine without a GPU fails for want of one, not of an LLVM): a GPU machine without LLVM renders
    natively in cuda_ad_rgb."""
    pytest.importorskip("mitsuba")
    env = {k: v for k, v in os.environ.items() if k != "DRJIT_LIBLLVM_PATH"}
    env.update(PYTHONPATH=SRC, NEUMAT_LIBLLVM_DIRS=str(tmp_path))
    r = subprocess.run([sys.executable, "-c", _VARIANT_WITHOUT_LLVM], env=env, capture_output=True, text=True,
                       timeout=120)
    lines = dict(line.split(" ", 1) for line in r.stdout.strip().splitlines())
    assert "no usable LLVM >= 16" in lines["llvm_ad_rgb"] and "libllvm19" in lines["llvm_ad_rgb"], lines
    assert lines["cuda_ad_rgb"] == "loaded" or (
        lines["cuda_ad_rgb"].startswith("refused: Mitsuba 3 with the cuda_ad_rgb variant failed to load")
        and "LLVM >= 16" not in lines["cuda_ad_rgb"]), lines
