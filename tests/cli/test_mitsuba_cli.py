"""`neumat mitsuba-render`: a Mitsuba scene file with a neumat BSDF chosen on the command line, and its errors."""
from __future__ import annotations

import pytest
from typer.testing import CliRunner

from neumat.cli.main import app
from neumat.io.images import read_image
from tests.mitsuba_util import mitsuba_or_skip

SCENE = """<scene version="3.0.0">
    <default name="mat" value="lambert"/>
    <integrator type="path"><integer name="max_depth" value="4"/></integrator>
    <sensor type="perspective">
        <float name="fov" value="30"/>
        <transform name="to_world"><lookat origin="0, 0, 4" target="0, 0, 0" up="0, 1, 0"/></transform>
        <film type="hdrfilm"><integer name="width" value="32"/><integer name="height" value="32"/></film>
        <sampler type="independent"><integer name="sample_count" value="4"/></sampler>
    </sensor>
    <shape type="sphere"><bsdf type="neumat"><string name="material" value="$mat"/></bsdf></shape>
    <emitter type="constant"><rgb name="radiance" value="1.0"/></emitter>
</scene>
"""


def _said(result) -> str:
    return "".join(result.output.split())


@pytest.mark.mitsuba
def test_white_furnace_through_the_cli(tmp_path):
    """A convex Lambertian sphere under a constant sky of 1 reflects its albedo: Mitsuba's MIS estimate of it is
    noisy per pixel but every sample is the albedo times one scalar (channel ratios exact)."""
    mitsuba_or_skip()
    scene, out = tmp_path / "scene.xml", tmp_path / "image.exr"
    scene.write_text(SCENE)
    r = CliRunner().invoke(app, ["mitsuba-render", str(scene), "-D", "mat=lambert:albedo=0.6/0.4/0.2",
                                 "--spp", "32", "-o", str(out)])
    assert r.exit_code == 0, r.output
    centre = read_image(out)[12:20, 12:20].reshape(-1, 3)
    assert abs(centre.mean(0) / [0.6, 0.4, 0.2] - 1).max() < 0.02
    assert abs(centre[:, 0] / centre[:, 2] - 3).max() < 1e-4 and abs(centre[:, 1] / centre[:, 2] - 2).max() < 1e-4


@pytest.mark.mitsuba
def test_errors_name_the_problem(tmp_path):
    mitsuba_or_skip()
    scene = tmp_path / "scene.xml"
    scene.write_text(SCENE)
    cases = [(["mitsuba-render", str(tmp_path / "none.xml"), "-o", "x.png"], "doesnotexist"),
             (["mitsuba-render", str(scene), "-D", "mat", "-o", "x.png"], "-Dexpectskey=value"),
             (["mitsuba-render", str(scene), "-D", "mat=/no/model.nmat", "-o", "x.png"], "doesnotexist"),
             (["mitsuba-render", str(scene), "-D", "mat=ggx:roughnes=0.2", "-o", "x.png"], "roughnes")]
    for args, message in cases:
        r = CliRunner().invoke(app, args)
        assert r.exit_code == 2, r.output
        assert message in _said(r), r.output


@pytest.mark.mitsuba
def test_malformed_scenes_are_one_line_errors(tmp_path):
    """Scenes Mitsuba loads but cannot render, and a mesh file of random bytes: one `error:` line, exit 2, no
    image (Mitsuba's exceptions used to print raw)."""
    mitsuba_or_skip()
    import numpy as np
    (tmp_path / "junk.ply").write_bytes(np.random.default_rng(0).bytes(4096))
    film = '<film type="hdrfilm"><integer name="width" value="{w}"/><integer name="height" value="{w}"/></film>'
    sensor = '<sensor type="perspective">' + film + '</sensor>'
    cases = {"no sensor": ('<integrator type="path"/><shape type="sphere"/>', "nosensor"),
             "no integrator": (sensor.format(w=8) + '<shape type="sphere"/>', "nointegrator"),
             "width 0": ('<integrator type="path"/>' + sensor.format(w=0) + '<shape type="sphere"/>', "0x0pixels"),
             "100000^2": ('<integrator type="path"/>' + sensor.format(w=100000) + '<shape type="sphere"/>',
                          "100000x100000pixels"),
             "random mesh": ('<integrator type="path"/>' + sensor.format(w=8) + '<shape type="ply"><string '
                             f'name="filename" value="{tmp_path / "junk.ply"}"/></shape>', "junk.ply")}
    for name, (body, message) in cases.items():
        scene = tmp_path / "scene.xml"
        scene.write_text(f'<scene version="3.0.0">{body}</scene>')
        r = CliRunner().invoke(app, ["mitsuba-render", str(scene), "-o", str(tmp_path / "x.png")])
        assert r.exit_code == 2 and message in _said(r), (name, r.output)
        assert r.output.startswith("error: ") and len(r.output.strip().splitlines()) == 1, (name, r.output)
        assert not (tmp_path / "x.png").exists()


def test_argument_errors_come_before_mitsuba(tmp_path, without_llvm):
    """Without a usable LLVM, the commands that need Mitsuba still name their own bad arguments first."""
    scene = tmp_path / "scene.xml"
    scene.write_text(SCENE)
    cases = [(["mitsuba-render", str(tmp_path / "none.xml"), "-o", str(tmp_path / "x.png")], "doesnotexist"),
             (["mitsuba-render", str(scene), "-D", "mat", "-o", str(tmp_path / "x.png")], "-Dexpectskey=value"),
             (["mitsuba-render", str(scene), "-o", str(tmp_path / "x.txt")], ".png"),
             (["render", "ggx", "--scene", f"mesh:{tmp_path / 'none.ply'}", "-o", str(tmp_path / "x.png")],
              "doesnotexist"),
             (["render", "ggx", "--scene", f"mesh:{scene}", "-o", str(tmp_path / "x.png")], ".ply")]
    for args, message in cases:
        r = CliRunner().invoke(app, args)
        assert r.exit_code == 2 and message in _said(r), r.output
    r = CliRunner().invoke(app, ["mitsuba-render", str(scene), "-o", str(tmp_path / "x.png")])
    assert r.exit_code == 2 and "libllvm19" in _said(r), r.output  # the refusal itself
    assert [p.name for p in tmp_path.iterdir()] == ["scene.xml"]


@pytest.mark.mitsuba
def test_the_variant_option(tmp_path):
    """--variant picks Mitsuba's variant: an unknown or non-RGB one is a one-line error naming the installed ones;
    cuda_ad_rgb on a machine without a GPU is a one-line error too (in a subprocess: a failed variant switch must
    not touch this process's Mitsuba), and renders where there is one."""
    import os
    import subprocess
    import sys
    from pathlib import Path
    mitsuba_or_skip()
    scene = tmp_path / "scene.xml"
    scene.write_text(SCENE)
    for variant, message in (("llvm_ad_rbg", "installedMitsubavariants"),
                             ("llvm_ad_spectral", "unpolarisedRGBvariant")):
        r = CliRunner().invoke(app, ["mitsuba-render", str(scene), "--variant", variant, "-o",
                                     str(tmp_path / "x.png")])
        assert r.exit_code == 2 and message in _said(r), (variant, r.output)
    src = str(Path(__file__).resolve().parents[2] / "src")
    r = subprocess.run([sys.executable, "-m", "neumat.cli.main", "mitsuba-render", str(scene), "--variant",
                        "cuda_ad_rgb", "--spp", "4", "-o", str(tmp_path / "gpu.exr")], capture_output=True, text=True,
                       timeout=300, env={**os.environ, "PYTHONPATH": src})
    import torch
    if torch.cuda.is_available():
        assert r.returncode == 0 and (tmp_path / "gpu.exr").is_file(), r.stderr
    else:
        assert r.returncode == 2 and r.stderr.startswith("error: ") and "cuda_ad_rgb" in r.stderr, r.stderr
        assert not (tmp_path / "gpu.exr").exists()
