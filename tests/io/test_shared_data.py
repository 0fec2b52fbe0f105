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
