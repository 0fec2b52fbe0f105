import json

import pytest
import torch
from typer.testing import CliRunner

from neumat.cli.main import app
from neumat.catalog.modelfile import save_model
from neumat.models.registry import build_model

from neumat.testing.parity import opengl_available
from neumat.testing.slang_parity import slang_available

needs_gl = pytest.mark.skipif(not opengl_available(), reason="no moderngl or no headless OpenGL 3.3 context (EGL)")


def _saved(tmp_path, spec):
    torch.manual_seed(0)
    return save_model(build_model(spec), tmp_path / "m.nmat")


def test_export_writes_glsl_textures_and_manifest(tmp_path):
    path = _saved(tmp_path, {"type": "multiscale", "spatial_size": 8})
    result = CliRunner().invoke(app, ["export", str(path), "-o", str(tmp_path / "glsl")])
    assert result.exit_code == 0, result.output
    manifest = json.loads((tmp_path / "glsl" / "manifest.json").read_text())
    assert sorted(manifest["textures"]) == ["neumat_diff", "neumat_half", "neumat_spatial"]
    assert "neumat_eval" in (tmp_path / "glsl" / "neumat.glsl").read_text()


@needs_gl
def test_export_check_runs_the_shader(tmp_path):
    path = _saved(tmp_path, {"type": "multiscale", "homogeneous": True})
    result = CliRunner().invoke(app, ["export", str(path), "-o", str(tmp_path / "glsl"), "--check", "500"])
    assert result.exit_code == 0, result.output
    rel = float(result.output.split("max relative difference ")[1].split(",")[0])
    assert rel < 1e-2


def test_export_refuses_a_model_without_a_shader(tmp_path):
    path = _saved(tmp_path, {"type": "nbrdf"})
    result = CliRunner().invoke(app, ["export", str(path), "-o", str(tmp_path / "glsl")])
    assert result.exit_code != 0 and "multi-scale model" in result.output


@needs_gl
def test_export_check_runs_a_sparse_btf(tmp_path):
    from neumat.methods.sparse_btf.model import SparseBTF
    from neumat.methods.sparse_btf.dictionary_train import train_dictionary

    from btf_util import synthetic_btf

    dictionary = train_dictionary([synthetic_btf(s) for s in (1, 2)], num_dictionaries=2, tau_train=(16, 4, 4),
                                  patch=4, max_iters=2)
    path = save_model(SparseBTF.encode(synthetic_btf(3), dictionary, (32, 8, 8)), tmp_path / "b.nmat")
    result = CliRunner().invoke(app, ["export", str(path), "-o", str(tmp_path / "glsl"), "--check", "500"])
    assert result.exit_code == 0, result.output
    manifest = json.loads((tmp_path / "glsl" / "manifest.json").read_text())
    assert manifest["textures"]["sbtf_codes"]["file"] == "sbtf_codes.f32"
    rel = float(result.output.split("max relative difference ")[1].split(",")[0])
    assert rel < 1e-4


@needs_gl
def test_export_check_runs_a_neupress(tmp_path):
    torch.manual_seed(0)
    model = build_model({"type": "neupress"})  # the paper's sizes and Fourier scale
    model.set_bounds(torch.tensor([-1.0, -1.0, -1.0]), torch.tensor([1.0, 1.0, 1.0]))
    path = save_model(model, tmp_path / "n.nmat")
    result = CliRunner().invoke(app, ["export", str(path), "-o", str(tmp_path / "glsl"), "--check", "300"])
    assert result.exit_code == 0, result.output
    manifest = json.loads((tmp_path / "glsl" / "manifest.json").read_text())
    assert "vec3 neumat_translucent(vec3 wi, vec3 x, vec3 wo)" in manifest["entry"]
    text = " ".join(result.output.split())
    assert float(text.split("S_hat max difference ")[1].split(" ")[0]) < 1e-3
    assert float(text.split("sigma max relative difference ")[1].split(" ")[0]) < 1e-3


@needs_gl
@pytest.mark.skipif(not slang_available(), reason="slangpy is not installed or its CPU device cannot be created")
def test_export_slang_check_runs_a_neupress(tmp_path):
    torch.manual_seed(0)
    model = build_model({"type": "neupress", "features": 7, "width": 12, "layers": 4, "sampler_hidden": [10, 6]})
    model.set_bounds(torch.tensor([-1.0, -1.0, -1.0]), torch.tensor([1.0, 1.0, 1.0]))
    path = save_model(model, tmp_path / "n.nmat")
    result = CliRunner().invoke(app, ["export", str(path), "-o", str(tmp_path / "out"), "--slang", "--check", "200"])
    assert result.exit_code == 0, result.output
    manifest = json.loads((tmp_path / "out" / "slang" / "manifest.json").read_text())
    assert manifest["interfaces"] == ["INeumatTranslucent", "INeumatTranslucentShade"]
    text = " ".join(result.output.split()).split("Slang module (CPU) vs torch: ")[1]
    assert float(text.split("S_hat max difference ")[1].split(" ")[0]) < 1e-4
    assert float(text.split("sigma max relative difference ")[1].split(" ")[0]) < 1e-4


@needs_gl
def test_export_check_runs_a_neubrdf_with_its_texture(tmp_path):
    path = _saved(tmp_path, {"type": "neubrdf", "nside": 8, "feature_dim": 8, "index_bits": 5, "hidden": 16,
                             "texture_height": 8, "texture_width": 8, "texture_channels": 4, "texture_levels": 2})
    result = CliRunner().invoke(app, ["export", str(path), "-o", str(tmp_path / "glsl"), "--check", "500",
                                      "--precision", "fp32"])
    assert result.exit_code == 0, result.output
    manifest = json.loads((tmp_path / "glsl" / "manifest.json").read_text())
    assert sorted(manifest["textures"]) == ["nbrdf_features", "nbrdf_index", "nbrdf_vertices", "neumat_spatial"]
    rel = float(result.output.split("max relative difference ")[1].split(",")[0])
    assert rel < 1e-4


@needs_gl
def test_export_check_runs_a_neubrdf_table_as_an_image_and_through_a_sampler(tmp_path):
    path = _saved(tmp_path, {"type": "neubrdf", "nside": 8, "feature_dim": 8, "index_bits": 5, "hidden": 16,
                             "interpolation": "uniform"})
    result = CliRunner().invoke(app, ["export", str(path), "-o", str(tmp_path / "glsl"), "--check", "500",
                                      "--precision", "fp32"])
    assert result.exit_code == 0, result.output
    assert "fastest under #version 420 core, where nbrdf_first is an image2DArray at image unit 0" in result.output
    manifest = json.loads((tmp_path / "glsl" / "manifest.json").read_text())
    assert manifest["textures"]["nbrdf_first"]["image_unit"] == 0
    for version in ("#version 420 core", "#version 330 core"):
        line = result.output.split(f"shader ({version}) vs torch on 500 Sec. 4.2 queries: ")[1]
        assert float(line.split("max relative difference ")[1].split(",")[0]) < 1e-4, version


def test_export_web_writes_the_viewer_page(tmp_path):
    path = _saved(tmp_path, {"type": "neubrdf", "nside": 4, "feature_dim": 4, "index_bits": 3, "hidden": 8})
    result = CliRunner().invoke(app, ["export", str(path), "-o", str(tmp_path / "glsl"), "--web"])
    assert result.exit_code == 0, result.output
    page = (tmp_path / "glsl" / "viewer.html").read_text()
    assert "<title>neumat viewer: neubrdf (m.nmat)</title>" in page and "nbrdf_index" in page


def test_export_slang_refuses_a_model_it_cannot_export(tmp_path):
    path = _saved(tmp_path, {"type": "nbrdf-uv", "spatial_size": 8})
    result = CliRunner().invoke(app, ["export", str(path), "-o", str(tmp_path / "out"), "--format", "slang"])
    assert result.exit_code == 2 and "export_slang" in result.output and "cartesian" in result.output
    assert not (tmp_path / "out").exists()


@needs_gl
@pytest.mark.skipif(not slang_available(), reason="slangpy is not installed or its CPU device cannot be created")
def test_export_slang_writes_and_checks_the_module(tmp_path):
    path = _saved(tmp_path, {"type": "neumip-frame", "spatial_size": 8, "hidden": 8, "hidden_layers": 1})
    result = CliRunner().invoke(app, ["export", str(path), "-o", str(tmp_path / "out"), "--slang", "--check", "300",
                                      "--precision", "fp32"])
    assert result.exit_code == 0, result.output
    manifest = json.loads((tmp_path / "out" / "slang" / "manifest.json").read_text())
    assert manifest["interfaces"] == ["INeumatMaterial"] and "neumat_spatial" in manifest["buffers"]
    assert (tmp_path / "out" / "neumat.glsl").exists()  # the GLSL export beside it, as without --slang
    text = " ".join(result.output.split())
    assert float(text.split("Slang module (CPU) vs torch on the same queries: max relative difference ")[1]
                 .split(",")[0]) < 1e-4


@needs_gl
@pytest.mark.skipif(not slang_available(), reason="slangpy is not installed or its CPU device cannot be created")
def test_export_defaults_to_fp16_and_reports_bytes_and_both_references(tmp_path):
    """The default precision: half files, half the bytes of fp32 in the summary, and --check against the torch
    model (within 2e-3) and against half_rounded(model) (float32 noise, 5e-5), for GLSL and Slang."""
    path = _saved(tmp_path, {"type": "neural-appearance", "spatial_size": 8})
    result = CliRunner().invoke(app, ["export", str(path), "-o", str(tmp_path / "out"), "--slang", "--check", "300"])
    assert result.exit_code == 0, result.output
    manifest = json.loads((tmp_path / "out" / "manifest.json").read_text())
    assert manifest["precision"] == "fp16" and manifest["textures"]["neumat_spatial"]["file"] == "neumat_spatial.f16"
    text = " ".join(result.output.split())
    assert "(fp16 / fp32 = 0.500); written: fp16" in text
    fp16 = int(text.split("stored bytes: fp16 ")[1].split(" = ")[1].split(";")[0])
    assert fp16 == manifest["bytes"]["total"]
    for run in ("shader (#version 420 core)", "shader (#version 330 core)", "Slang module (CPU)"):
        torch_rel = float(text.split(f"{run} vs torch on ")[1].split("max relative difference ")[1].split(",")[0])
        half_rel = float(text.split(f"{run} vs torch with the halves stored (half_rounded): max relative "
                                    "difference ")[1].split(",")[0])
        assert torch_rel < 2e-3 and half_rel < 5e-5, (run, torch_rel, half_rel)


def test_export_says_whether_a_neural_appearance_model_is_its_own_fp16_export(tmp_path):
    """A model trained in fp32 to its end is rounded on export (said so, with the recipe option that avoids it);
    a half-aware fit's (here: snapped) model is exactly what the fp16 export stores."""
    from neumat.models.half_precision import snap_to_half_

    torch.manual_seed(0)
    model = build_model({"type": "neural-appearance", "spatial_size": 8})
    with torch.no_grad():
        for p in model.parameters():
            p.add_(torch.randn_like(p) * 0.1)
    for name in ("plain", "snapped"):
        path = save_model(model if name == "plain" else snap_to_half_(model), tmp_path / f"{name}.nmat")
        result = CliRunner().invoke(app, ["export", str(path), "-o", str(tmp_path / name)])
        assert result.exit_code == 0, result.output
        text = " ".join(result.output.split())
        rounded, exact = "rounded to the nearest half on export" in text, "are the stored halves" in text
        assert (rounded, exact) == ((True, False) if name == "plain" else (False, True)), text
        assert ("half_finish" in text) == (name == "plain")
