"""`neumat translucent prt | prt-render` end to end on a tiny sphere (42 vertices, 2 x 4 view bins), and their
errors on wrong inputs."""
from __future__ import annotations

import pytest
import torch
from typer.testing import CliRunner

from neumat.catalog.modelfile import load_model, save_model
from neumat.cli.main import app
from neumat.core.config import config_to_dict
from neumat.fit.translucent_observations import Observations
from neumat.io.images import read_image
from neumat.methods.neupress.model import NeuPreSS
from neumat.methods.neupress.prt import FAST_PRECISION, PRTConfig, SHPRT
from neumat.reflectance.translucent import TranslucentConfig
from neumat.render.mesh import icosphere, vertex_normals
from tests.mitsuba_util import mitsuba_or_skip


def _run(*args):
    return CliRunner().invoke(app, ["translucent", *map(str, args)])


def _said(result) -> str:
    return "".join(result.output.split())


def _observations(path, source=True):
    x = torch.tensor([[0.0, 0.0, 1.0]]).repeat(4, 1)
    box = [[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]]
    Observations(x, x, x, x, x).save(path, source={"object": config_to_dict(TranslucentConfig()), "bbox": box}
                                     if source else None)
    return path


def _model(path):
    torch.manual_seed(0)
    m = NeuPreSS(features=8, width=8, layers=2, sampler_hidden=(4,))
    m.set_bounds(-torch.ones(3), torch.ones(3))
    return save_model(m, path)


@pytest.mark.mitsuba
def test_prt_and_prt_render_on_a_small_sphere(tmp_path):
    mitsuba_or_skip()
    obs, model, table = _observations(tmp_path / "o.npz"), _model(tmp_path / "m.nmat"), tmp_path / "t.prt"
    r = _run("prt", model, obs, "-o", table, "--view-bins", "2x4", "--light-samples", 16, "--subdivisions", 1, "-q")
    assert r.exit_code == 0, r.output
    said = _said(r)
    assert "42" in said and "2x4" in said and str(42 * 8 * 9 * 3 * 2) in said  # vertices, bins, fp16 bytes
    assert FAST_PRECISION in said
    prt = SHPRT.load(table)
    v, f = icosphere(1)
    assert torch.equal(prt.faces, f) and prt.config.view_phi == 4 and prt.config.precision == FAST_PRECISION
    cfg = PRTConfig(view_theta=2, view_phi=4, light_samples=16, precision=FAST_PRECISION)
    direct = SHPRT.from_material(load_model(model), v.float(), vertex_normals(v, f).float(), cfg)
    torch.testing.assert_close(prt.coefficients, direct.coefficients, rtol=1e-5, atol=1e-7)

    r = _run("prt-render", table, obs, "-o", tmp_path / "a.exr", "--resolution", 8, "--spp", 1, "--env-width", 16)
    assert r.exit_code == 0, r.output
    img = read_image(tmp_path / "a.exr")
    assert img.shape == (8, 8, 3) and float(img.max()) > 0

    r = _run("prt-render", table, obs, "-o", tmp_path / "c.png", "--resolution", 8, "--spp", 1, "--env-width", 16,
             "--model", model, "--model-spp", 2, "--reference-spp", 1)
    assert r.exit_code == 0, r.output
    said = _said(r)
    assert said.count("FLIP") == 1 and "SHPRT" in said and said.count("reference") >= 2
    assert read_image(tmp_path / "c.png").ndim == 3


def test_prt_errors_name_the_problem(tmp_path, without_llvm):
    """Without a usable LLVM too: each argument is checked before Mitsuba loads."""
    obs, model = _observations(tmp_path / "o.npz"), _model(tmp_path / "m.nmat")
    r = _run("prt", model, obs, "-o", tmp_path / "t.npz")
    assert r.exit_code == 2 and ".prt" in _said(r)
    r = _run("prt", obs, obs, "-o", tmp_path / "t.prt")
    assert r.exit_code == 2 and ".nmat" in _said(r)
    r = _run("prt", model, model, "-o", tmp_path / "t.prt")
    assert r.exit_code == 2 and ".npz" in _said(r)
    from neumat.models.registry import build_model
    other = save_model(build_model({"type": "naive-mlp"}), tmp_path / "other.nmat")
    r = _run("prt", other, obs, "-o", tmp_path / "t.prt")
    assert r.exit_code == 2 and "NeuPreSS" in _said(r)
    r = _run("prt", model, _observations(tmp_path / "plain.npz", source=False), "-o", tmp_path / "t.prt")
    assert r.exit_code == 2 and "objectdescription" in _said(r)
    for bins in ("8by16", "0x4", "8x"):
        r = _run("prt", model, obs, "-o", tmp_path / "t.prt", "--view-bins", bins)
        assert r.exit_code == 2 and "THETAxPHI" in _said(r), bins
    r = _run("prt", model, obs, "-o", tmp_path / "t.prt", "--precision", "fp16")
    assert r.exit_code == 2 and "precision" in _said(r) and "bf16" in _said(r)
    r = _run("prt-render", model, obs, "-o", tmp_path / "i.png")
    assert r.exit_code == 2 and ".prt" in _said(r)
    (tmp_path / "junk.prt").write_bytes(b"not a table")
    r = _run("prt-render", tmp_path / "junk.prt", obs, "-o", tmp_path / "i.png")
    assert r.exit_code == 2 and "SHPRT" in _said(r)
    r = _run("prt-render", tmp_path / "junk.prt", obs, "-o", tmp_path / "i.exr", "--reference-spp", 2)
    assert r.exit_code == 2 and ".png" in _said(r)
