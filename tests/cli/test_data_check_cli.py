"""`neumat data info`, `neumat data convert`, `neumat check`, `neumat version` through the real CLI app."""
from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from neumat import __version__
from neumat.cli.main import app
from neumat.io.merl import MERL_DIMS, MERL_SCALE, read_merl, write_merl

runner = CliRunner()


def _json(result) -> dict:
    assert result.exit_code == 0, result.output
    return json.loads(result.stdout)


def test_version():
    r = runner.invoke(app, ["version"])
    assert r.exit_code == 0 and r.stdout.strip() == __version__


def test_info_merl(tmp_path):
    table = np.full((3, *MERL_DIMS), 750.0)
    table[1, 0, 0, :3] = -1.0  # three missing cells
    path = tmp_path / "grey.binary"
    write_merl(path, table)
    d = _json(runner.invoke(app, ["data", "info", str(path), "--json"]))
    assert d["kind"].startswith("MERL") and d["size_on_disk_bytes"] == path.stat().st_size
    assert d["missing_entries"] == 3 and d["valid"] is True
    assert d["value_min"] == pytest.approx(750 * MERL_SCALE[0]) and d["value_max"] == pytest.approx(750 * MERL_SCALE[2])


def test_info_rgl(shared_data):
    d = _json(runner.invoke(app, ["data", "info", str(shared_data / "rgl/paper_white_rgb.bsdf"), "--json"]))
    assert d["kind"].startswith("RGL") and d["isotropic"] is True and d["valid"] is True
    assert "paper" in d["description"].lower() and 0 <= d["value_min"] < d["value_max"]


def test_info_spec_and_errors(tmp_path):
    d = _json(runner.invoke(app, ["data", "info", "lambert:albedo=0.5", "--json"]))
    assert d["kind"] == "analytic material"
    assert d["sampled_value_min"] == pytest.approx(0.5 / np.pi) == pytest.approx(d["sampled_value_max"])
    bad = tmp_path / "short.binary"
    bad.write_bytes(b"\x5a\x00\x00\x00" * 3 + b"\x00" * 100)
    for arg, words in ((str(bad), "header"), ("nosuchmodel:x=1", "unknown"), (str(tmp_path / "none.bsdf"), "exist")):
        r = runner.invoke(app, ["data", "info", arg])
        assert r.exit_code == 2 and "error" in r.output and words in r.output, r.output


def test_convert_analytic_to_merl(tmp_path):
    out = tmp_path / "lam.binary"
    r = runner.invoke(app, ["data", "convert", "lambert:albedo=0.3/0.6/0.9", "-o", str(out)])
    assert r.exit_code == 0, r.output
    t = read_merl(out).table
    valid = t[0] >= 0
    for c, a in enumerate((0.3, 0.6, 0.9)):
        np.testing.assert_allclose(t[c][valid] * MERL_SCALE[c], a / np.pi, rtol=1e-6)
    r = runner.invoke(app, ["data", "convert", "lambert", "-o", str(tmp_path / "x.png")])
    assert r.exit_code == 2 and ".binary" in r.output


def test_check_passes_for_lambert_and_reports_json():
    d = _json(runner.invoke(app, ["check", "lambert:albedo=1", "--angles", "10,60", "--samples", "20000",
                                  "--json"]))
    assert d["passed"] is True and d["reciprocity_passed"] is True
    for row in d["angles"]:
        assert row["chi2_passed"] is True
        # directional albedo of a white Lambertian surface is 1 (within 5 standard errors)
        assert all(abs(a - 1) <= 5 * row["albedo_stderr"] + 1e-6 for a in row["albedo_rgb"])


def test_check_tests_a_spatially_varying_material_at_a_texel(tmp_path):
    """A layered .json (white Lambert under a smudged clear coat) is checked at --uv: it samples correctly and
    reflects all light (albedo 1 within 5 standard errors plus the coat albedo table's 3e-3)."""
    spec = {"type": "layered", "base": "lambert:albedo=1", "samples": 4,
            "coats": [{"roughness": {"smudges": {"size": 16}, "low": 0.1, "high": 0.4}}]}
    (tmp_path / "coated.json").write_text(json.dumps(spec))
    d = _json(runner.invoke(app, ["check", str(tmp_path / "coated.json"), "--angles", "40", "--samples", "20000",
                                  "--uv", "0.3,0.6", "--json"]))
    assert d["passed"] is True and d["uv"] == "0.3,0.6"
    row = d["angles"][0]
    assert all(abs(a - 1) <= 5 * row["albedo_stderr"] + 3e-3 for a in row["albedo_rgb"]), row
    r = runner.invoke(app, ["check", str(tmp_path / "coated.json"), "--uv", "0.5"])
    assert r.exit_code != 0 and "--uv" in r.output


def test_check_passes_a_neural_sampler_that_leaves_the_hemisphere(tmp_path):
    """A neural-appearance model's sampler sends specular samples below the horizon with their pdf: `check`
    tests over the whole sphere, where it passes (over the hemisphere it reported p = 0 for every model)."""
    import torch
    from neumat.catalog.modelfile import save_model
    from neumat.models.registry import load_all
    torch.manual_seed(0)
    save_model(load_all().get("neural-appearance")(spatial_size=8), tmp_path / "na.nmat")
    r = runner.invoke(app, ["check", str(tmp_path / "na.nmat"), "--angles", "60", "--samples", "50000", "--json"])
    d = json.loads(r.stdout)  # exit code 1: an untrained model is not reciprocal (reciprocity_passed false)
    assert r.exit_code == (0 if d["passed"] else 1) and d["angles"][0]["chi2_passed"] is True, d


def test_data_info_loads_models_and_names_btfs(tmp_path):
    import torch
    from neumat.catalog.modelfile import save_model
    from neumat.io.btf import BTFTable, write_btf
    from neumat.models.registry import load_all
    save_model(load_all().get("ggx")(), tmp_path / "g.nmat")
    d = _json(runner.invoke(app, ["data", "info", str(tmp_path / "g.nmat"), "--json"]))
    assert d["kind"] == "neumat model (ggx)" and d["valid"] is True and d["sampled_value_max"] > 0
    assert "output_bound" not in d
    gated = load_all().get("multiscale")(spatial_size=8)
    gated.observe_targets(torch.tensor([[0.5, 2.0, 81.75]]))
    save_model(gated, tmp_path / "m.nmat")
    d = _json(runner.invoke(app, ["data", "info", str(tmp_path / "m.nmat"), "--json"]))
    assert d["output_bound"] == "0.5, 2, 81.75"
    dirs = torch.tensor([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8]])
    write_btf(tmp_path / "b.nbtf", BTFTable(torch.full((2, 2, 4, 4, 3), 0.25), dirs, dirs, "flat"))
    d = _json(runner.invoke(app, ["data", "info", str(tmp_path / "b.nbtf"), "--json"]))
    assert d["kind"] == "neumat BTF (.nbtf)" and d["resolution"].startswith("4 x 4 texels, 2 light x 2 view")
    assert d["value_min"] == d["value_max"] == 0.25 and d["valid"] is True


def test_check_rejects_bad_angles():
    r = runner.invoke(app, ["check", "lambert", "--angles", "95"])
    assert r.exit_code == 2 and "--angles" in r.output


def test_open_material_reads_a_texture_set_folder(shared_data):
    from neumat import open_material
    from neumat.reflectance.svbrdf import SVBRDF

    m = open_material(shared_data / "svbrdf" / "Paper001_1K", max_size=32)
    assert isinstance(m, SVBRDF) and m.spatially_varying


def test_open_material_rejects_unknown_reader_options(shared_data):
    from neumat import InputError, open_material

    with pytest.raises(InputError, match="unknown reader option.*frobnicate.*known: height_scale, max_size"):
        open_material(shared_data / "svbrdf" / "Paper001_1K", frobnicate=1)
    with pytest.raises(InputError, match="unknown reader option"):
        open_material(shared_data / "rgl" / "paper_white_rgb.bsdf", max_size=3)
    with pytest.raises(InputError, match="spec string"):
        open_material("lambert", max_size=3)
