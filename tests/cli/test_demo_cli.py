"""`neumat demo` end to end at toy size: fit, runtime model file, renders, comparison picture, HTML report, web
viewer page."""
from __future__ import annotations

import json
import re

import pytest
import torch
from typer.testing import CliRunner

from neumat import Query, load
from neumat.cli.main import app
from neumat.export.web.headless import chromium, viewer_pixels
from neumat.export.web.scene import View, viewer_image
from neumat.io.images import read_image
from neumat.models.half_precision import half_rounded


def test_demo_writes_report_model_and_pictures(tmp_path):
    out = tmp_path / "demo"
    r = CliRunner().invoke(app, ["demo", "-o", str(out), "--source", "plastic:diffuse=0.4/0.2/0.1,roughness=0.2",
                                 "--steps", "5", "--set", "nside=4", "--set", "hidden=8", "--spp", "2",
                                 "--resolution", "24"])
    assert r.exit_code == 0, r.output
    html = (out / "report.html").read_text()
    assert html.startswith("<!DOCTYPE html>") and len(re.findall(r'<img src="data:image/png;base64,', html)) >= 4
    model = load(out / "neubrdf.nmat")
    assert model.is_runtime and model.cfg.features == "vq"  # the shipped form, as `neumat fit` writes it
    assert "preset recommended" in r.output and "model.direction_inputs=hd_warp" in r.output
    metrics = json.loads((out / "metrics.json").read_text())
    for key in ("flip", "ssim", "noise_floor_flip", "bytes_fp16", "fit_seconds"):
        assert isinstance(metrics[key], (int, float)), key
    assert 0 <= metrics["noise_floor_flip"] <= metrics["flip"] <= 1  # a 5-step fit is far above the floor
    assert "of the 20000 x 16384 target evaluations" in html  # the budget against the paper's
    for name in ("reference", "neubrdf"):
        img = read_image(out / f"{name}.exr")
        assert img.shape == (24, 24, 3) and (img >= 0).all() and img.max() > 0
    assert read_image(out / "compare.png").shape[1] >= 3 * 24
    wi = torch.tensor([[0.0, 0.6, 0.8]])
    assert torch.isfinite(model.eval(Query(wi, wi))).all()
    page = (out / "viewer.html").read_text()
    assert "neumat viewer: NeuBRDF fitted to plastic" in page and "nm_vec2pix" in page


def test_demo_reports_a_bad_source(tmp_path):
    r = CliRunner().invoke(app, ["demo", "-o", str(tmp_path), "--source", "nosuch:x=1", "--steps", "1"])
    assert r.exit_code == 2 and "unknown" in r.output


@pytest.mark.skipif(chromium() is None, reason="no chromium on PATH (Debian: apt-get install chromium)")
def test_demo_viewer_renders_the_model_the_report_renders(tmp_path):
    """The page shows the shipped (runtime) model that the report's renders show: no facets one has and the other
    lacks (headless Chromium against the torch model in the viewer's scene)."""
    out = tmp_path / "demo"
    r = CliRunner().invoke(app, ["demo", "-o", str(out), "--steps", "5", "--set", "nside=4", "--set", "hidden=8",
                                 "--spp", "1", "--resolution", "16", "-q"])
    assert r.exit_code == 0, r.output
    model = load(out / "neubrdf.nmat")
    view = View(elevation=0.6, azimuth=1.0, exposure=1.0)
    pixels = viewer_pixels(out / "viewer.html", view, 40, 32)
    reference = viewer_image(half_rounded(model), view, 40, 32)
    assert model.is_runtime and float((reference.amax(-1) > 0).float().mean()) > 0.1
    error = (pixels[..., :3] - reference).abs() / reference.abs().clamp(min=1e-3 * float(reference.max()))
    assert float(error.max()) < 1e-3, float(error.max())
