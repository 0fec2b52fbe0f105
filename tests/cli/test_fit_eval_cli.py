"""`neumat fit` and `neumat eval` through typer's CliRunner, on a local app (independent of cli/main.py)."""
from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
import torch
import typer
from typer.testing import CliRunner

from neumat.catalog.modelfile import load_model, save_model
from neumat.catalog.open_material import open_material
from neumat.io.modelfile import read_header
from neumat.methods.neubrdf.model import NeuBRDF

from cli_util import fitting_app, output_text

SMALL = ["--set", "nside=2", "--set", "index_bits=3", "--set", "hidden=8", "--set", "batch_size=256",
         "--set", "log_every=5"]


@pytest.fixture
def app() -> typer.Typer:
    return fitting_app()


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
    assert h["metrics"]["fit_cpu_seconds"] > 0 and "CPU s" in res.stdout  # what the fit cost, recorded and said
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


def test_threads_sets_torch_threads_for_the_fit_only(app, teacher, tmp_path, monkeypatch):
    """--threads N: the fit runs with N torch threads; the caller's count comes back after it (also after a
    failed fit); 0 is refused."""
    from neumat.fit import trainer

    seen, real_fit = [], trainer.fit
    monkeypatch.setattr(trainer, "fit", lambda *a, **k: (seen.append(torch.get_num_threads()), real_fit(*a, **k))[1])
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        args = ["fit", teacher, *SMALL, "--steps", "2", "--quiet"]
        res = CliRunner().invoke(app, [*args, "--threads", "1", "-o", str(tmp_path / "a.nmat")])
        assert res.exit_code == 0, res.output
        assert seen == [1] and torch.get_num_threads() == 2
        res = CliRunner().invoke(app, [*args, "--threads", "1", "--set", "nside=-1", "-o", str(tmp_path / "b.nmat")])
        assert res.exit_code != 0 and torch.get_num_threads() == 2
        assert CliRunner().invoke(app, [*args, "--threads", "0", "-o", str(tmp_path / "c.nmat")]).exit_code == 2
    finally:
        torch.set_num_threads(before)


def test_fit_analytic_spec(app, tmp_path):
    out = tmp_path / "m.nmat"
    res = CliRunner().invoke(app, ["fit", "plastic:roughness=0.3", *SMALL, "--steps", "5", "--quiet", "-o", str(out)])
    assert res.exit_code == 0, res.output
    assert read_header(out)["source"]["name"] == "plastic:roughness=0.3"


@pytest.mark.parametrize("args, match", [
    (["--set", "nsides=4"], "unknown key 'nsides'.*did you mean model.nside"),
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
    assert re.search(match, output_text(res)), res.output


def test_fit_non_brdf_source_and_bad_output(app, tmp_path):
    textured = save_model(NeuBRDF(nside=2, index_bits=3, hidden=8, texture_height=2, texture_width=2,
                                  texture_channels=2), tmp_path / "textured.nmat")
    res = CliRunner().invoke(app, ["fit", str(textured), *SMALL, "--steps", "1", "-o", str(tmp_path / "x.nmat")])
    assert res.exit_code == 2 and "spatially varying" in output_text(res)
    res = CliRunner().invoke(app, ["fit", str(textured), "-o", str(tmp_path / "x.pt")])
    assert res.exit_code == 2 and ".nmat" in output_text(res)


def test_eval_json(app, teacher, tmp_path):
    pytest.importorskip("neumat.metrics.hdr")
    res = CliRunner().invoke(app, ["eval", teacher, "--against", teacher, "--json", "--n-configs", "4096",
                                   "--no-image"])
    assert res.exit_code == 0, res.output
    row = json.loads(res.stdout)
    assert row["rmse_hdr"] == 0.0 and row["rel_err"] == 0.0  # a model against itself
    assert row["bytes_fp16"] == load_model(teacher).size_bytes("fp16")
    assert row["evals_per_second"] > 0
    assert "ssim" not in row


def test_eval_with_image_table(app, teacher):
    pytest.importorskip("neumat.render.render")
    pytest.importorskip("neumat.metrics.image")
    res = CliRunner().invoke(app, ["eval", teacher, "--against", "lambert", "--n-configs", "2048", "--spp", "2",
                                   "--resolution", "8"])
    assert res.exit_code == 0, res.output
    for key in ("rmse_hdr", "psnr", "flip", "bytes_fp16", "evals_per_second"):
        assert key in res.stdout


def test_eval_picture_shows_the_renderings_it_scored(app, teacher, tmp_path):
    """--picture: reference | model | FLIP error | the floor's FLIP error, drawn from the renderings it scored (the
    picture made from them again is the same, bit for bit); the same scores as without it; refused with --no-image
    or a suffix that is not an image, before any work."""
    from PIL import Image

    from neumat.render.comparison import comparison_images, reference_renders
    from neumat.viz.compare import comparison_picture

    args = ["eval", teacher, "--against", "lambert", "--n-configs", "2048", "--spp", "2", "--resolution", "16",
            "--json"]
    out = tmp_path / "eval.png"
    res = CliRunner().invoke(app, [*args, "--picture", str(out)])
    assert res.exit_code == 0, res.output
    row = json.loads(res.stdout)
    plain = json.loads(CliRunner().invoke(app, args).stdout)
    assert {k: v for k, v in row.items() if k != "evals_per_second"} == \
        {k: v for k, v in plain.items() if k != "evals_per_second"}
    ref = open_material("lambert")
    renders = reference_renders(ref, 2, 16, 0, "cpu")
    test = comparison_images({"m": load_model(teacher)}, 2, 16, 0, "cpu")["m"]
    expected = comparison_picture(renders, test, Path(teacher).stem, row)
    assert np.array_equal(np.asarray(Image.open(out)), expected)
    res = CliRunner().invoke(app, [*args, "--no-image", "--picture", str(out)])
    assert res.exit_code == 2 and "--no-image" in output_text(res)
    res = CliRunner().invoke(app, [*args, "--picture", str(tmp_path / "eval.exr")])
    assert res.exit_code == 2 and ".png" in output_text(res)


def test_eval_missing_model(app, tmp_path):
    res = CliRunner().invoke(app, ["eval", str(tmp_path / "none.nmat"), "--against", "lambert", "--no-image"])
    assert res.exit_code == 2 and "does not exist" in output_text(res)


def test_fit_neubrdf_at_defaults_writes_the_small_runtime_form(app, tmp_path):
    """The file is the shipped form (packed 9-bit indices, fp16 codebook and MLP: under 200 KB at the paper's
    N_side 64, within 2x of the reported bytes), not the 102 MB of training logits, which only the checkpoint
    keeps; it evaluates bit for bit like the runtime form of the fitted (EMA) weights; eval scores it."""
    from neumat.core.query import Query

    out, ckpt = tmp_path / "m.nmat", tmp_path / "fit.ckpt"
    res = CliRunner().invoke(app, ["fit", "plastic:roughness=0.3", "--preset", "paper", "--steps", "2", "--device",
                                   "cpu", "--quiet", "--checkpoint", str(ckpt), "-o", str(out)])
    assert res.exit_code == 0, res.output
    h = read_header(out)
    assert h["runtime"] and h["config"]["nside"] == 64 and h["config"]["index_bits"] == 9
    size = out.stat().st_size
    assert size < 200_000 and size < 2 * h["size_bytes"]["fp16"] and ckpt.stat().st_size > 100e6
    reference = NeuBRDF()
    reference.load_state_dict(torch.load(ckpt, weights_only=False)["ema"])  # the fitted weights, training form
    reference.runtime()
    gen = torch.Generator().manual_seed(0)
    wi, wo = (torch.nn.functional.normalize(torch.randn(4096, 3, generator=gen), dim=-1).abs() for _ in range(2))
    with torch.no_grad():
        assert torch.equal(load_model(out).eval(Query(wi, wo)), reference.eval(Query(wi, wo)))
    res = CliRunner().invoke(app, ["eval", str(out), "--against", "plastic:roughness=0.3", "--json", "--n-configs",
                                   "4096", "--no-image"])
    assert res.exit_code == 0, res.output
    assert json.loads(res.stdout)["bytes_fp16"] == h["size_bytes"]["fp16"]


def test_fit_on_cpu_picks_the_cpu_recipe_and_says_so(app, teacher, tmp_path):
    """Without --steps on a CPU the CPU-sized recipe runs and one line names it and the paper's; --recipe paper
    picks the paper's (here with --set steps to keep the test short: --set fields still apply)."""
    from neumat.fit.method import recipe_for

    cpu, paper = recipe_for("neubrdf", "cpu"), recipe_for("neubrdf", "paper")
    assert cpu.steps * cpu.batch_size < paper.steps * paper.batch_size
    args = ["fit", teacher, *SMALL, "--device", "cpu"]
    res = CliRunner().invoke(app, [*args, "--set", "steps=3", "--recipe", "cpu", "-o", str(tmp_path / "c.nmat")])
    assert res.exit_code == 0, res.output
    h = read_header(tmp_path / "c.nmat")
    assert h["recipe"]["steps"] == 3 and h["recipe"]["lr_decay_every"] == cpu.lr_decay_every
    res = CliRunner().invoke(app, [*args, "--set", "steps=3", "--recipe", "paper", "-o", str(tmp_path / "p.nmat")])
    assert res.exit_code == 0, res.output
    assert read_header(tmp_path / "p.nmat")["recipe"]["lr_decay_every"] == paper.lr_decay_every
    assert "the paper's exact model" not in res.output
    res = CliRunner().invoke(app, [*args, "--set", "steps=3", "--recipe", "dense", "-o", str(tmp_path / "d.nmat")])
    assert res.exit_code == 0, res.output
    h = read_header(tmp_path / "d.nmat")
    assert (h["recipe"]["loss"], h["recipe"]["options"]["direction_features"]) == ("log_cos_eps", 10.0)
    assert h["config"]["features"] == "dense"
    res = CliRunner().invoke(app, [*args, "--preset", "gpu", "-o", str(tmp_path / "x.nmat")])
    assert res.exit_code == 2 and "no preset 'gpu'" in output_text(res)


def test_fit_without_options_runs_the_recommended_preset_and_says_so(app, teacher, tmp_path, monkeypatch):
    """Through the command with no preset: the recommended one runs (its steps shortened by patching the method's
    recipe, so that the test stays fast), one line names it, its overrides and how to get the paper's model, and the
    file records it."""
    from dataclasses import replace

    from neumat.fit.method import method_for

    recipes = method_for("neubrdf").recipes
    monkeypatch.setitem(recipes, "cpu", replace(recipes["cpu"], steps=4))
    res = CliRunner().invoke(app, ["fit", teacher, *SMALL, "--device", "cpu", "-o", str(tmp_path / "c.nmat")])
    assert res.exit_code == 0, res.output
    text = output_text(res)
    assert "neubrdf: preset recommended (recipe cpu; model.features=dense, model.direction_inputs=hd_warp" in text
    assert "4 steps x 256" in text and "the paper's exact model: --preset paper" in text
    h = read_header(tmp_path / "c.nmat")
    assert h["preset"]["name"] == "recommended" and h["config"]["direction_inputs"] == "hd_warp"
    assert h["recipe"]["lr_decay_every"] == recipes["cpu"].lr_decay_every


def test_the_preset_line_names_the_steps_given(app, teacher, tmp_path):
    """--steps shortens the fit, and the line printed before it starts says so (it once named the recipe's)."""
    res = CliRunner().invoke(app, ["fit", teacher, *SMALL, "--steps", "3", "--device", "cpu",
                                   "-o", str(tmp_path / "s.nmat")])
    assert res.exit_code == 0, res.output
    assert "preset recommended" in output_text(res) and "3 steps x 256" in output_text(res)
    assert read_header(tmp_path / "s.nmat")["recipe"]["steps"] == 3


def test_cpu_recipe_with_direction_inputs_fits_quantises_and_exports(app, tmp_path, monkeypatch):
    """--set direction_inputs=hd through the CPU recipe's phases (coarse, dense, k-means, VQ; steps shortened):
    the file is the codebook model with the 6 inputs, it evaluates as written, and its GLSL export carries them."""
    from dataclasses import replace

    from neumat.export.glsl import export_glsl
    from neumat.fit.method import method_for

    recipes = method_for("neubrdf").recipes
    monkeypatch.setitem(recipes, "cpu", replace(recipes["cpu"], steps=20))
    out = tmp_path / "hd.nmat"
    res = CliRunner().invoke(app, ["fit", "plastic:roughness=0.3", "--recipe", "cpu", "--set", "nside=4",
                                   "--set", "index_bits=3", "--set", "hidden=8", "--set", "batch_size=256",
                                   "--set", "direction_inputs=hd", "--device", "cpu", "--quiet", "-o", str(out)])
    assert res.exit_code == 0, res.output
    h = read_header(out)
    assert h["config"]["direction_inputs"] == "hd" and h["config"]["features"] == "vq" and h["runtime"]
    model = load_model(out)
    assert model.mlp.net[0].weight.shape[1] == 2 * 16 + 6
    assert "nm_hd(wi, wo, hd)" in export_glsl(model).source
    res = CliRunner().invoke(app, ["fit", "plastic:roughness=0.3", "--steps", "2", "--set", "nside=2",
                                   "--set", "direction_inputs=nbrdf", "--device", "cpu", "-o", str(out)])
    assert res.exit_code == 2 and "direction_inputs" in output_text(res)


def test_eval_and_compare_take_source_options(app, teacher, monkeypatch):
    """--source-option reaches the reader of the reference, as fit's does (an analytic spec takes none: the
    error says so); compare passes them to its first material only."""
    import neumat.catalog.open_material as opener
    from neumat.cli import rendering

    res = CliRunner().invoke(app, ["eval", teacher, "--against", "lambert", "--source-option", "max_size=64",
                                   "--no-image", "--n-configs", "256"])
    assert res.exit_code == 2 and "max_size" in output_text(res)
    seen = []
    real = opener.open_material
    monkeypatch.setattr(opener, "open_material", lambda name, **kw: seen.append((name, kw)) or real(name))
    res = CliRunner().invoke(app, ["eval", teacher, "--against", "lambert", "--source-option", "max_size=64",
                                   "--no-image", "--n-configs", "256", "--json"])
    assert res.exit_code == 0, res.output
    assert seen == [("lambert", {"max_size": 64})]
    rendering.register(app)
    seen.clear()
    res = CliRunner().invoke(app, ["compare", "lambert", teacher, "--source-option", "max_size=64", "--spp", "1",
                                   "--resolution", "8", "--n-configs", "256", "--json"])
    assert res.exit_code == 0, res.output
    assert seen == [("lambert", {"max_size": 64}), (teacher, {})]
