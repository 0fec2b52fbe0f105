"""`neumat render` and `neumat compare` through the real CLI app, at toy sizes."""
from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from neumat.cli.main import app
from neumat.io.images import read_image

runner = CliRunner()
SMALL = ["--spp", "2", "--resolution", "16"]


@pytest.mark.parametrize("suffix", [".png", ".exr"])
def test_render_writes_an_image(tmp_path, suffix):
    out = tmp_path / f"sphere{suffix}"
    r = runner.invoke(app, ["render", "lambert:albedo=0.5", "--light", "const:1", "--strategy", "material", *SMALL,
                            "-o", str(out)])
    assert r.exit_code == 0, r.output
    img = read_image(out)
    assert img.shape == (16, 16, 3)
    if suffix == ".exr":
        # Lambert 0.5 under a unit constant environment, cosine sampling: exactly 0.5 where every sample hits
        # the sphere, 1 (the environment) where none does, in between on the silhouette
        assert (np.abs(img - 0.5) < 1e-3).all(-1).sum() > 100
        assert img.min() > 0.5 - 1e-3 and img.max() < 1 + 1e-3


def test_compare_prints_json_and_writes_a_picture(tmp_path):
    out = tmp_path / "cmp.png"
    r = runner.invoke(app, ["compare", "lambert:albedo=0.5", "lambert:albedo=0.5", "lambert:albedo=0.4", *SMALL,
                            "--n-configs", "4096", "--json", "-o", str(out)])
    assert r.exit_code == 0, r.output
    d = json.loads(r.stdout)
    same, darker = d["results"]
    assert same["rmse_hdr"] == 0 and d["floor"].keys() == {k for k in same if k in d["floor"]}
    assert all(same[k] == d["floor"][k] for k in d["floor"])  # the reference itself scores exactly the floor
    assert darker["mae_hdr"] == pytest.approx(0.1 / np.pi, rel=1e-4) and darker["flip"] > 0 < d["floor"]["mae"]
    assert "16x spp" in d["protocol"]
    assert read_image(out).shape[0] >= 2 * 16  # one row per compared material


@pytest.mark.parametrize("args, words", [
    (["render", "lambert", "--scene", "cube", "-o", "x.png"], "cube"),
    (["render", "lambert", "--light", "env:/no/such.hdr", "-o", "x.png"], "such.hdr"),
    (["render", "nosuch:a=1", "-o", "x.png"], "unknown"),
    (["compare", "lambert"], "at least one other"),
])
def test_bad_input_gives_one_line_errors(tmp_path, args, words):
    args = [str(tmp_path / a) if a == "x.png" else a for a in args]
    r = runner.invoke(app, args)
    assert r.exit_code == 2 and "error" in r.output and words in r.output, r.output
