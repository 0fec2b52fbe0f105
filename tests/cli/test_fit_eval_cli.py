"""`neumat fit` and `neumat eval` through typer's CliRunner, on a local app (independent of cli/main.py)."""
from __future__ import annotations

import json
import re

import pytest
import torch
import typer
from typer.testing import CliRunner

from neumat.cli import fitting
from neumat.catalog.modelfile import load_model, save_model
from neumat.io.modelfile import read_header
from neumat.models.neubrdf import NeuBRDF

SMALL = ["--set", "nside=2", "--set", "index_bits=3", "--set", "hidden=8", "--set", "batch_size=256",
         "--set", "log_every=5"]


def _text(res) -> str:
    """The command's output with rich's line wrapping undone."""
    return " ".join(res.output.split())


@pytest.fixture
def app() -> typer.Typer:
    app = typer.Typer(pretty_exceptions_enable=False, add_completion=False)
    fitting.register(app)
    return app


@pytest.fixture
def teacher(tmp_path) -> str:
    """A small NeuBRDF saved as .nmat: a source that needs no other part of the package."""
    torch.manual_seed(1)
    return str(save_model(NeuBRDF(nside=2, index_bits=3, hidden=8), tmp_path / "teacher.nmat"))


def test_fit_writes_a_model_with_overrides_applied(app, teacher, tmp_path):
    out = tmp_path / "student.nmat"
    res = CliRunner().invoke(app, ["fit", teacher, "--model", "neubrdf", *SMALL, "--steps", "10", "--seed", "3",
                                   "--device", "cpu", "--quiet", "-o", str(out)])
    assert res.exit_code == 0, res.output
    assert "wrote" in res.stdout
    h = read_header(out)
    assert h["config"]["nside"] == 2 and h["config"]["hidden"] == 8
    assert h["recipe"]["batch_size"] == 256 and h["recipe"]["steps"] == 10 and h["recipe"]["seed"] == 3
    assert h["source"]["name"] == "teacher.nmat" and h["metrics"]["final_loss"] > 0
    assert isinstance(load_model(out), NeuBRDF)


def test_fit_is_reproducible_and_resumable(app, teacher, tmp_path):
    args = ["fit", teacher, *SMALL, "--steps", "10", "--quiet"]
    r1 = CliRunner().invoke(app, [*args, "-o", str(tmp_path / "a.nmat")])
    r2 = CliRunner().invoke(app, [*args, "--checkpoint", str(tmp_path / "c.ckpt"), "-o", str(tmp_path / "b.nmat")])
    r3 = CliRunner().invoke(app, [*args, "--checkpoint", str(tmp_path / "c.ckpt"), "--resume",
                                  "-o", str(tmp_path / "c.nmat")])
    assert r1.exit_code == r2.exit_code == r3.exit_code == 0, r1.output + r2.output + r3.output
    a, b, c = (load_model(tmp_path / f"{x}.nmat").state_dict() for x in "abc")
    assert all(torch.equal(a[k], b[k]) and torch.equal(a[k], c[k]) for k in a)


def test_fit_analytic_spec(app, tmp_path):
    out = tmp_path / "m.nmat"
    res = CliRunner().invoke(app, ["fit", "plastic:roughness=0.3", *SMALL, "--steps", "5", "--quiet", "-o", str(out)])
    assert res.exit_code == 0, res.output
    assert read_header(out)["source"]["name"] == "plastic:roughness=0.3"


@pytest.mark.parametrize("args, match", [
    (["--set", "nsides=4"], "unknown key.*'nsides' \\(did you mean nside"),
    (["--set", "index_bits=0"], "index_bits"),
    (["--set", "nside=2.5"], "nside"),
    (["--set", "nside=-4"], "nside"),
    (["--set", "lr=-1"], "Recipe.lr"),
    (["--set", "nside"], "key=value"),
    (["--model", "neubrdff"], "unknown model 'neubrdff'"),
])
def test_fit_bad_arguments(app, teacher, tmp_path, args, match):
    res = CliRunner().invoke(app, ["fit", teacher, *args, "--steps", "1", "--quiet", "-o", str(tmp_path / "x.nmat")])
    assert res.exit_code == 2
    assert re.search(match, _text(res)), res.output


def test_fit_non_brdf_source_and_bad_output(app, tmp_path):
    textured = save_model(NeuBRDF(nside=2, index_bits=3, hidden=8, texture_height=2, texture_width=2,
                                  texture_channels=2), tmp_path / "textured.nmat")
    res = CliRunner().invoke(app, ["fit", str(textured), *SMALL, "--steps", "1", "-o", str(tmp_path / "x.nmat")])
    assert res.exit_code == 2 and "spatially varying" in _text(res)
    res = CliRunner().invoke(app, ["fit", str(textured), "-o", str(tmp_path / "x.pt")])
    assert res.exit_code == 2 and ".nmat" in _text(res)


def test_eval_json(app, teacher, tmp_path):
    pytest.importorskip("neumat.metrics.hdr")
    res = CliRunner().invoke(app, ["eval", teacher, "--against", teacher, "--json", "--n", "4096", "--no-image"])
    assert res.exit_code == 0, res.output
    row = json.loads(res.stdout)
    assert row["rmse_hdr"] == 0.0 and row["rel_err"] == 0.0  # a model against itself
    assert row["bytes_fp16"] == load_model(teacher).size_bytes("fp16")
    assert row["evals_per_second"] > 0
    assert "ssim" not in row


def test_eval_with_image_table(app, teacher):
    pytest.importorskip("neumat.render.render")
    pytest.importorskip("neumat.metrics.image")
    res = CliRunner().invoke(app, ["eval", teacher, "--against", "lambert", "--n", "2048", "--spp", "2",
                                   "--resolution", "8"])
    assert res.exit_code == 0, res.output
    for key in ("rmse_hdr", "psnr", "flip", "bytes_fp16", "evals_per_second"):
        assert key in res.stdout


def test_eval_missing_model(app, tmp_path):
    res = CliRunner().invoke(app, ["eval", str(tmp_path / "none.nmat"), "--against", "lambert", "--no-image"])
    assert res.exit_code == 2 and "does not exist" in _text(res)
