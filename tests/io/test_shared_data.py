"""Where the reference data is looked up: $NEUMAT_SHARED_DATA first, then beside the checkout, then from the
working directory (an installed wheel run from the checkout)."""
from __future__ import annotations

from neumat.io import shared_data


def test_environment_variable_wins_then_the_working_directory(tmp_path, monkeypatch):
    data = tmp_path / "elsewhere"
    data.mkdir()
    monkeypatch.setenv("NEUMAT_SHARED_DATA", str(data))
    assert shared_data.shared_data_dir() == data.resolve()
    monkeypatch.delenv("NEUMAT_SHARED_DATA")
    monkeypatch.setattr(shared_data, "CHECKOUT_DATA", tmp_path / "no" / "such")
    (tmp_path / "shared" / "data").mkdir(parents=True)
    (tmp_path / "repo").mkdir()
    monkeypatch.chdir(tmp_path / "repo")
    assert shared_data.shared_data_dir() == (tmp_path / "shared" / "data").resolve()
    monkeypatch.chdir(tmp_path)
    assert shared_data.shared_data_dir() is None
    assert (tmp_path / "no" / "such").resolve() in shared_data.shared_data_candidates()


def test_paths_resolve_inside_the_data_folder_and_to_the_shipped_examples(tmp_path, monkeypatch):
    """`NEUMAT_SHARED_DATA=... neumat data info mats/c.json` and docs/examples/... run from anywhere (a wheel)."""
    from typer.testing import CliRunner

    from neumat.cli.main import app
    data = tmp_path / "data"
    (data / "mats").mkdir(parents=True)
    (data / "mats" / "c.json").write_text('{"type": "layered", "base": "lambert", "coats": [{"roughness": 0.1}]}')
    (tmp_path / "work").mkdir()
    monkeypatch.chdir(tmp_path / "work")
    monkeypatch.setenv("NEUMAT_SHARED_DATA", str(data))
    assert shared_data.resolve_data_path("mats/c.json") == (data / "mats" / "c.json").resolve()
    assert shared_data.resolve_data_path("../shared/data/mats/c.json") == (data / "mats" / "c.json").resolve()
    assert shared_data.resolve_data_path("mats/none.json") == shared_data.Path("mats/none.json")
    assert shared_data.resolve_data_path("docs/examples/scene.xml") == shared_data.EXAMPLES / "scene.xml"
    for name in ("mats/c.json", "docs/examples/coated.json"):
        r = CliRunner().invoke(app, ["data", "info", name, "--json"])
        assert r.exit_code == 0 and '"kind": "material file (.json)"' in r.output, r.output


def test_the_documented_examples_are_package_data():
    """docs/examples is a link to the shipped folder, whose every file pyproject's package-data puts in the wheel."""
    import fnmatch
    import tomllib
    from pathlib import Path
    root = Path(__file__).resolve().parents[2]
    assert (root / "docs" / "examples").resolve() == shared_data.EXAMPLES
    patterns = tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]["neumat"]
    files = sorted(p.relative_to(shared_data.EXAMPLES.parent).as_posix() for p in shared_data.EXAMPLES.iterdir())
    assert {"examples/scene.xml", "examples/coated.json"} <= set(files)
    assert [f for f in files if not any(fnmatch.fnmatch(f, p) for p in patterns)] == []


def test_the_tests_read_the_folder_neumat_shared_data_names(tmp_path):
    import os
    import subprocess
    import sys
    from pathlib import Path
    root = Path(__file__).resolve().parents[2]
    r = subprocess.run([sys.executable, "-c", "import tests.conftest as c; print(c.SHARED_DATA)"], cwd=root,
                       env={**os.environ, "NEUMAT_SHARED_DATA": str(tmp_path), "PYTHONPATH": str(root / "src")},
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and r.stdout.strip() == str(tmp_path.resolve()), r.stderr
