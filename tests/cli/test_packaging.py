"""Packaging: `neumat --version`, `python -m neumat`, the licence, the typing marker and the user extras."""
from __future__ import annotations

import subprocess
import sys
import tomllib
from pathlib import Path

from typer.testing import CliRunner

import neumat
from neumat.cli.main import app

ROOT = Path(__file__).resolve().parents[2]


def test_version_option_and_python_dash_m():
    res = CliRunner().invoke(app, ["--version"])
    assert res.exit_code == 0 and res.output.strip() == f"neumat {neumat.__version__}"
    out = subprocess.run([sys.executable, "-m", "neumat", "--version"], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and out.stdout.strip() == f"neumat {neumat.__version__}", out.stderr


def test_licence_typing_marker_and_extras():
    meta = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert meta["license"] == "BSD-3-Clause" and "BSD 3-Clause" in (ROOT / meta["license-files"][0]).read_text()
    assert (Path(neumat.__file__).parent / "py.typed").is_file()
    extras = meta["optional-dependencies"]
    assert {d.split(">")[0] for d in extras["export"]} == {"moderngl", "slangpy"}
    assert any(d.startswith("mitsuba") for d in extras["mitsuba"])
    assert [d.split(">")[0] for d in extras["ray"]] == ["ray"] and "ray" in {d.split(">")[0] for d in extras["dev"]}
    assert "OpenEXR>=3.3" in meta["dependencies"]  # the code uses OpenEXR.File, added in 3.3
