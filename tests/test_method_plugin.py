"""A method added in its own folder, with no edit anywhere else, works end to end: `tests/plugin_methods/toy_lambert`,
loaded through NEUMAT_METHODS, is listed with its presets, fits through `neumat fit`, saves and loads, exports as
GLSL (and the web page) whose shader matches the model, and passes the conformance suite."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from neumat.testing.parity import opengl_available

ROOT = Path(__file__).resolve().parents[1]
PLUGINS = ROOT / "tests" / "plugin_methods"


def _env() -> dict:
    return {**os.environ, "NEUMAT_METHODS": "toy_lambert",
            "PYTHONPATH": os.pathsep.join([str(PLUGINS), str(ROOT / "src"), os.environ.get("PYTHONPATH", "")])}


def _neumat(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "neumat", *args], cwd=cwd, env=_env(), capture_output=True,
                          text=True, timeout=300)


def test_the_toy_method_is_listed_fits_saves_loads_and_exports(tmp_path):
    listed = _neumat("list", "--json", cwd=tmp_path)
    assert listed.returncode == 0, listed.stderr
    toy = next(m for m in json.loads(listed.stdout)["models"] if m["name"] == "toy-lambert")
    assert toy["recipe"] and "recommended" in toy["presets"] and "glsl" in toy["exports"]

    fit = _neumat("fit", "lambert:albedo=0.2/0.4/0.6", "--model", "toy-lambert", "-o", "toy.nmat",
                  "--device", "cpu", cwd=tmp_path)
    assert fit.returncode == 0, fit.stdout + fit.stderr
    assert "preset recommended" in fit.stdout and "recipe.lr=0.1" in fit.stdout

    from neumat.io.modelfile import read_model_file

    header, tensors = read_model_file(tmp_path / "toy.nmat")
    assert header["preset"] == {"name": "recommended", "overrides": {"recipe.lr": 0.1}}
    albedo = tensors["log_albedo"].exp()
    assert albedo.sub(albedo.new_tensor([0.2, 0.4, 0.6])).abs().max() < 0.02, albedo  # the fit found the albedo

    args = ["export", "toy.nmat", "-o", "out", "--format", "glsl", "--format", "web", "--precision", "fp32"]
    if opengl_available():
        args += ["--check", "64"]
    exported = _neumat(*args, cwd=tmp_path)
    assert exported.returncode == 0, exported.stdout + exported.stderr
    assert (tmp_path / "out" / "neumat.glsl").exists() and (tmp_path / "out" / "viewer.html").exists()
    if opengl_available():
        rel = float(exported.stdout.split("max relative difference ")[1].split(",")[0])
        assert rel < 1e-6, exported.stdout


def test_the_toy_method_passes_the_conformance_suite(tmp_path):
    run = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-k", "toy-lambert",
                          str(ROOT / "tests" / "models" / "test_conformance.py")],
                         cwd=ROOT, env=_env(), capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stdout[-3000:]
    assert " passed" in run.stdout and " failed" not in run.stdout, run.stdout[-2000:]


def test_an_unimportable_plugin_is_one_clear_error(tmp_path):
    run = subprocess.run([sys.executable, "-m", "neumat", "list"], cwd=tmp_path, capture_output=True, text=True,
                         env={**_env(), "NEUMAT_METHODS": "no_such_method_module"}, timeout=120)
    assert run.returncode != 0 and "NEUMAT_METHODS" in run.stderr and "Traceback" not in run.stderr, run.stderr
