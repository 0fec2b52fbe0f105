"""`neumat data texture-set` (a procedural set written as a folder) and `neumat data texture-stats` (its regime)
through the real CLI app: the folder reads back as the generator's set, the JSON statistics are the library's,
bad input is one clear error."""
from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from neumat.cli.main import app
from neumat.io.texture_set import load_texture_set
from neumat.reflectance.detail_texture import detail_texture_set
from neumat.reflectance.procedural_texture import procedural_texture_set
from neumat.reflectance.texture_statistics import texture_statistics

from cli_util import output_text

runner = CliRunner()


@pytest.mark.parametrize("kind, make", [("brushed", detail_texture_set), ("polished", detail_texture_set),
                                        ("weave", procedural_texture_set)])
def test_texture_set_writes_a_folder_that_reads_back(tmp_path, kind, make):
    out = tmp_path / kind
    res = runner.invoke(app, ["data", "texture-set", kind, "-o", str(out), "--size", "24", "--seed", "3"])
    assert res.exit_code == 0, res.output
    back, ref = load_texture_set(out), make(kind, 24, 3)
    assert back.size == (24, 24)
    assert (back.roughness - ref.roughness).abs().max() < 2e-5 and (back.normal - ref.normal).abs().max() < 0.01


def test_texture_stats_prints_the_library_statistics(tmp_path):
    folder = tmp_path / "scratches"
    assert runner.invoke(app, ["data", "texture-set", "scratches", "-o", str(folder), "--size", "32"]).exit_code == 0
    res = runner.invoke(app, ["data", "texture-stats", str(folder), "--footprints", "1,4", "--samples", "2",
                              "--crop", "16", "--json"])
    assert res.exit_code == 0, res.output
    got = json.loads(res.stdout)
    ref = texture_statistics(load_texture_set(folder, crop=16), (1, 4), samples=2)
    assert got == json.loads(json.dumps(ref))
    assert got["size"] == [16, 16] and set(got["separability_rank"]) == {"1", "4"}
    moved = runner.invoke(app, ["data", "texture-stats", str(folder), "--footprints", "1", "--samples", "2",
                                "--crop", "16", "--crop-origin", "8,12", "--json"])
    assert moved.exit_code == 0, moved.output
    ref = texture_statistics(load_texture_set(folder, crop=16, crop_origin=(8, 12)), (1,), samples=2)
    assert json.loads(moved.stdout) == json.loads(json.dumps(ref)) and json.loads(moved.stdout) != got
    table = runner.invoke(app, ["data", "texture-stats", str(folder), "--footprints", "2", "--samples", "2"])
    assert table.exit_code == 0 and "separability rank at 2 texel(s)" in output_text(table)


@pytest.mark.parametrize("args, message", [
    (["texture-set", "wood", "-o", "x"], "unknown kind 'wood'"),
    (["texture-stats", "FOLDER", "--footprints", "1,a"], "--footprints: expected numbers"),
    (["texture-stats", "FOLDER", "--footprints", "0"], "expected positive numbers"),
    (["texture-stats", "nowhere"], "does not exist"),
    (["texture-stats", "FOLDER", "--crop", "8", "--crop-origin", "1;2"], "--crop-origin: expected ROW,COL"),
    (["texture-stats", "FOLDER", "--crop-origin", "1,2"], "crop_origin"),
])
def test_bad_input_is_one_clear_error(tmp_path, args, message):
    folder = tmp_path / "set"
    runner.invoke(app, ["data", "texture-set", "foil", "-o", str(folder), "--size", "16"])
    args = [str(folder) if a == "FOLDER" else str(tmp_path / a) if a in ("x", "nowhere") else a for a in args]
    res = runner.invoke(app, ["data", *args])
    assert res.exit_code == 2, res.output
    assert "error:" in res.output and message in output_text(res)
