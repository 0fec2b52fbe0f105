"""Hostile inputs to every reader and command: each must end in one clear error (exit code 1 or 2), with no
traceback, no signal, no hang, nothing left behind and any previous output untouched (issue 26).

In-process (typer's CliRunner) wherever the failure cannot kill or block the test process; in a subprocess
with a timeout where the old failure was a signal (Mitsuba on a bad mesh) or a hang (a FIFO). Add a case here
with every new reader or command.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from neumat.cli.main import app

SRC = str(Path(__file__).resolve().parents[2] / "src")
PREVIOUS = b"previous output, must survive"

TRIANGLE = ("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
            "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 {}\n")


def png_declaring(width: int, height: int) -> bytes:
    """A PNG whose header declares width x height RGB pixels, with one byte of image data."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return len(data).to_bytes(4, "big") + kind + data + zlib.crc32(kind + data).to_bytes(4, "big")
    ihdr = width.to_bytes(4, "big") + height.to_bytes(4, "big") + bytes([8, 2, 0, 0, 0])
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\0")) + chunk(b"IEND", b"")


def write_texture_set(folder: Path, roughness: Path | None = None) -> Path:
    """A valid 4 x 4 texture set (color, normal; roughness unless given) in `folder`."""
    from PIL import Image
    folder.mkdir()
    Image.new("RGB", (4, 4), (200, 30, 30)).save(folder / "x_Color.png")
    Image.new("RGB", (4, 4), (128, 128, 255)).save(folder / "x_NormalGL.png")
    if roughness is None:
        Image.new("L", (4, 4), 128).save(folder / "x_Roughness.png")
    return folder


def rgl_fields(**override) -> dict:
    """The fields of a small valid isotropic RGL file, some replaced by `override`."""
    rng = np.random.default_rng(0)
    fields = {"description": "test", "phi_i": np.zeros(1, np.float32),
              "theta_i": np.linspace(0, np.pi / 2, 3, dtype=np.float32),
              "ndf": rng.random((2, 8), dtype=np.float32) + 0.1, "sigma": rng.random((2, 8), dtype=np.float32) + 0.5,
              "vndf": rng.random((1, 3, 8, 8), dtype=np.float32) + 0.1,
              "luminance": rng.random((1, 3, 4, 4), dtype=np.float32) + 0.1,
              "rgb": rng.random((1, 3, 3, 4, 4), dtype=np.float32), "jacobian": np.ones(1, np.uint8)}
    return {**fields, **override}


def write_models(t: Path) -> None:
    """Broken `.nmat` files under `t`, each from a valid small model: NaN, integer, missing and mis-shaped
    weights, NeuBRDF pruning levels outside the hierarchy, and a NeuBRDF config of nside 2^20."""
    from neumat.catalog.modelfile import save_model
    from neumat.io.modelfile import read_model_file, write_model_file
    from neumat.models.registry import load_all

    torch.manual_seed(0)
    save_model(load_all().get("ggx")(), t / "good.nmat")
    save_model(load_all().get("neubrdf")(nside=2, index_bits=2, hidden=4), t / "neubrdf.nmat")
    header, weights = read_model_file(t / "good.nmat")
    name = next(k for k, v in weights.items() if v.is_floating_point())
    variants = {"nan": {**weights, name: torch.full_like(weights[name], float("nan"))},
                "int": {**weights, name: weights[name].long()},
                "missing": {k: v for k, v in weights.items() if k != name},
                "misshaped": {**weights, name: torch.zeros(7, 7)}}
    for kind, tensors in variants.items():
        write_model_file(t / f"{kind}.nmat", header, tensors)
    header, weights = read_model_file(t / "neubrdf.nmat")
    write_model_file(t / "levels.nmat", header, {**weights, "level_i": torch.full_like(weights["level_i"], 9)})
    write_model_file(t / "huge.nmat", {**header, "config": {**header["config"], "nside": 2 ** 20}}, weights)


def write_observations(t: Path) -> None:
    """Translucent observation files under `t`: empty, truncated, with 0 and 1 observations, non-unit normals."""
    from neumat.fit.translucent_observations import Observations

    up = torch.tensor([[0.0, 0.0, 1.0]]).repeat(8, 1)
    Observations(up, up, up, up, up).save(t / "obs.npz")
    (t / "empty.npz").write_bytes(b"")
    (t / "truncated.npz").write_bytes((t / "obs.npz").read_bytes()[:200])
    for n in (0, 1):
        Observations(up[:n], up[:n], up[:n], up[:n], up[:n]).save(t / f"obs{n}.npz")
    np.savez(t / "nonunit.npz", x=up.numpy(), n=2 * up.numpy(), wo=up.numpy(), wi=up.numpy(), value=up.numpy())
    Observations(up, up, up, up, -up).save(t / "negative.npz")  # every value -1: no Monte Carlo difference
    for name, source in {"src_list": [1, 2], "src_bbox": {"bbox": "x"}, "src_seed": {"seed": "one"},
                         "src_object": {"object": {"nope": 1}}, "src_extra": {"colour": 1}}.items():
        Observations(up, up, up, up, up).save(t / f"{name}.npz", source=source)
    (t / "obs.npz").unlink()


def write_btfs(t: Path) -> None:
    """`.nbtf` files under `t` with a chunk dtype that differs from the header, and with negative values."""
    from safetensors.torch import load_file, save_file
    from safetensors import safe_open
    from neumat.io.btf import BTFTable, write_btf

    dirs = torch.tensor([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8]])
    write_btf(t / "ok.nbtf", BTFTable(torch.rand(2, 2, 4, 4, 3), dirs, dirs, "ok"))
    with safe_open(str(t / "ok.nbtf"), "pt") as f:
        meta = f.metadata()
    tensors = load_file(t / "ok.nbtf")
    save_file({**tensors, "light_00001": tensors["light_00001"].float()}, t / "dtype.nbtf", metadata=meta)
    save_file({**tensors, "light_00001": -tensors["light_00001"]}, t / "negative.nbtf", metadata=meta)
    save_file(tensors, t / "label.nbtf", metadata={"neumat_btf": json.dumps({**json.loads(meta["neumat_btf"]),
                                                                            "label": [1]})})
    (t / "ok.nbtf").unlink()


def write_broken_data(t: Path) -> None:
    """Measured files under `t` that read but hold values no material can use."""
    from neumat.io.images import write_image
    from neumat.io.merl import MERL_DIMS
    from neumat.io.rgl import write_tensor_file

    f = rgl_fields()
    write_tensor_file(t / "zero_vndf.bsdf", rgl_fields(vndf=np.zeros_like(f["vndf"])))
    write_tensor_file(t / "nan_theta.bsdf", rgl_fields(theta_i=np.array([0, np.nan, 1.5], np.float32)))
    write_tensor_file(t / "descending.bsdf", rgl_fields(theta_i=f["theta_i"][::-1].copy()))
    write_tensor_file(t / "negative.bsdf", rgl_fields(rgb=-f["rgb"] - 0.1))
    write_tensor_file(t / "overflow.bsdf", {"x": np.zeros(1, np.float32)})  # its shape is patched below
    raw = bytearray((t / "overflow.bsdf").read_bytes())  # magic, version, count, name "x", ndim 1, dtype, offset
    raw[32:40] = (2 ** 63 - 1).to_bytes(8, "little")
    (t / "overflow.bsdf").write_bytes(bytes(raw))
    (t / "missing.binary").write_bytes(np.asarray(MERL_DIMS, "<i4").tobytes()
                                       + np.full(3 * 90 * 90 * 180, -1.0, "<f8").tobytes())
    image = np.ones((4, 8, 3), np.float32)
    image[1, 2, 0] = -1e6
    write_image(t / "negative.exr", image)
    layered = '{{"type": "layered", "base": "{}", "coats": [{{"roughness": 0.1}}]}}'
    (t / "cycle_a.json").write_text(layered.format("cycle_b.json"))
    (t / "cycle_b.json").write_text(layered.format("cycle_a.json"))
    (t / "cycle_self.json").write_text(layered.format("cycle_self.json"))
    (t / "smudge_seed.json").write_text('{"type": "layered", "base": "lambert", "coats": [{"roughness": '
                                        '{"smudges": {"seed": "one", "size": 16}, "low": 0.1, "high": 0.3}}]}')
    (t / "bomb.png").write_bytes(png_declaring(100000, 100000))


def _files(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): (p.read_bytes() if p.is_file() else b"<dir>")
            for p in sorted(folder.rglob("*")) if not p.is_fifo()}


def _bad_cases(t: Path) -> dict[str, list[str]]:
    """name -> command line; inputs are made under `t`; `t/out.png` and `t/out.nbtf` hold previous outputs."""
    (t / "bad.ply").write_text(TRIANGLE.format(99999))
    (t / "folder.png").mkdir()
    (t / "huge.png").write_bytes(png_declaring(100000, 100000))
    (t / "huge.hdr").write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 1000000000 +X 1000000000\n" + bytes(64))
    (t / "neg.hdr").write_bytes(b"")
    (t / "empty.binary").write_bytes(b"")
    (t / "truncated.nmat").write_bytes(b"\x10\x00\x00")
    (t / "self.json").write_text('{"type": "layered", "base": "self.json", "coats": [{"roughness": 0.1}]}')
    (t / "notes.txt").write_text("not a material")
    out, nbtf = str(t / "out.png"), str(t / "out.nbtf")
    return {
        "device-unknown": ["render", "lambert", "--device", "foo", "-o", out],
        "device-cuda-missing": ["render", "lambert", "--device", "cuda:7", "-o", out],
        "seed-overflow": ["render", "lambert", "--seed", str(2 ** 70), "-o", out],
        "seed-negative": ["render", "lambert", "--seed", "-1", "-o", out],
        "resolution-huge": ["render", "lambert", "--resolution", "100000", "-o", out],
        "out-is-folder": ["render", "lambert", "--resolution", "8", "-o", str(t / "folder.png")],
        "out-under-a-file": ["render", "lambert", "--resolution", "8", "-o", str(t / "notes.txt" / "x.png")],
        "out-wrong-suffix": ["render", "lambert", "--resolution", "8", "-o", str(t / "x.txt")],
        "light-nan": ["render", "lambert", "--light", "point:nan/0/0", "--resolution", "8", "-o", out],
        "light-inf": ["render", "lambert", "--light", "point:inf/0/0", "--resolution", "8", "-o", out],
        "light-negative": ["render", "lambert", "--light", "const:-1", "--resolution", "8", "-o", out],
        "light-dir-inf": ["render", "lambert", "--light", "dir:inf/0/0", "--resolution", "8", "-o", out],
        "env-huge-png": ["render", "lambert", "--light", f"env:{t / 'huge.png'}", "--resolution", "8", "-o", out],
        "env-huge-hdr": ["render", "lambert", "--light", f"env:{t / 'huge.hdr'}", "--resolution", "8", "-o", out],
        "env-empty-hdr": ["render", "lambert", "--light", f"env:{t / 'neg.hdr'}", "--resolution", "8", "-o", out],
        "mesh-bad-index": ["render", "lambert", "--scene", f"mesh:{t / 'bad.ply'}", "--resolution", "8", "-o", out],
        "material-empty-merl": ["render", str(t / "empty.binary"), "--resolution", "8", "-o", out],
        "material-truncated-nmat": ["render", str(t / "truncated.nmat"), "--resolution", "8", "-o", out],
        "material-folder-not-set": ["render", str(t / "folder.png"), "--resolution", "8", "-o", out],
        "material-layered-self": ["render", str(t / "self.json"), "--resolution", "8", "-o", out],
        "material-unknown-suffix": ["render", str(t / "notes.txt"), "--resolution", "8", "-o", out],
        "compare-one": ["compare", "lambert", "--resolution", "8"],
        "btf-wrong-suffix": ["data", "btf-generate", "procedural:bumps", "-o", str(t / "b.png"), "--size", "8"],
        "btf-size-huge": ["data", "btf-generate", "procedural:bumps", "-o", nbtf, "--size", "100000"],
        "btf-size-zero": ["data", "btf-generate", "procedural:bumps", "-o", nbtf, "--size", "0"],
        "btf-device": ["data", "btf-generate", "procedural:bumps", "-o", nbtf, "--size", "8", "--device", "foo"],
        "convert-to-folder": ["data", "convert", "lambert", "-o", str(t / "folder.png")],
        "info-missing": ["data", "info", str(t / "none.binary")],
        "dictionary-patch-zero": ["fit-dictionary", nbtf, "-o", str(t / "d.nmat"), "--patch", "0"],
        "dictionary-iterations-zero": ["fit-dictionary", nbtf, "-o", str(t / "d.nmat"), "--iterations", "0"],
        "dictionary-not-a-btf": ["fit-dictionary", nbtf, "-o", str(t / "d.nmat")],
        **{name: args for name, (args, _) in _checked_cases(t).items()},
    }


def _checked_cases(t: Path) -> dict[str, tuple[list[str], str]]:
    """name -> (command line, what its one-line error must say), on the files `write_*` make under `t`."""
    write_models(t)
    write_observations(t)
    write_btfs(t)
    write_broken_data(t)
    out = str(t / "out.png")
    fit = ["fit", "-m", "dipole-bssrdf", "--steps", "1", "-o", str(t / "m.nmat")]
    return {
        "info-rgl-zero-vndf": (["data", "info", str(t / "zero_vndf.bsdf")], "'vndf' is zero everywhere"),
        "info-rgl-nan-theta": (["data", "info", str(t / "nan_theta.bsdf")], "'theta_i' has 1 NaN"),
        "info-rgl-descending-theta": (["data", "info", str(t / "descending.bsdf")], "strictly ascending"),
        "info-rgl-all-negative": (["data", "info", str(t / "negative.bsdf")], "'rgb' has no positive value"),
        "info-rgl-shape-overflow": (["data", "info", str(t / "overflow.bsdf")], "(truncated)"),
        "info-merl-all-missing": (["data", "info", str(t / "missing.binary")], "every value is negative (missing)"),
        "info-nmat-nan": (["data", "info", str(t / "nan.nmat")], "NaN or infinite value(s)"),
        "info-nmat-int": (["data", "info", str(t / "int.nmat")], "is stored as torch.int64, expected torch.float32"),
        "info-nmat-missing": (["data", "info", str(t / "missing.nmat")], "Missing key(s)"),
        "info-nmat-misshaped": (["data", "info", str(t / "misshaped.nmat")], "size mismatch"),
        "info-nmat-levels": (["data", "info", str(t / "levels.nmat")], "pruning levels in [0, 1]"),
        "info-nmat-nside-huge": (["data", "info", str(t / "huge.nmat")], "GiB of memory"),
        "info-nbtf-dtype": (["data", "info", str(t / "dtype.nbtf")], "is float32, but the header says dtype"),
        "info-nbtf-negative": (["data", "info", str(t / "negative.nbtf")], "are negative"),
        "convert-nmat-nan": (["data", "convert", str(t / "nan.nmat"), "-o", str(t / "x.binary")], "NaN or infinite"),
        "eval-against-nan": (["eval", str(t / "good.nmat"), "--against", str(t / "nan.nmat"), "--no-image",
                              "--n-configs", "64"], "nan.nmat"),
        "info-png-huge": (["data", "info", str(t / "bomb.png")], "exceeds limit of 178956970 pixels"),
        "env-negative-pixel": (["render", "lambert", "--light", f"env:{t / 'negative.exr'}", "--resolution", "8",
                                "-o", out], "negative value"),
        "layered-cycle": (["render", str(t / "cycle_a.json"), "--resolution", "8", "-o", out],
                          "cycle_b.json -> "),
        "layered-self": (["data", "info", str(t / "cycle_self.json")], "its base leads back to itself"),
        "btf-png-suffix": (["data", "btf-generate", "procedural:bumps", "-o", str(t / "b.png"), "--size", "8"],
                           ".nbtf"),
        "fit-lr-nan": (["fit", "lambert", "-m", "ggx", "--set", "lr=nan", "-o", str(t / "m.nmat")], "Recipe.lr"),
        "fit-obs-empty": ([*fit, str(t / "empty.npz")], "empty.npz: not a neumat observations file"),
        "fit-obs-truncated": ([*fit, str(t / "truncated.npz")], "truncated.npz: not a neumat observations file"),
        "fit-obs-zero": ([*fit, str(t / "obs0.npz")], "observations are empty"),
        "fit-obs-one": ([*fit, str(t / "obs1.npz")], "leaves none to train on"),
        "fit-obs-non-unit": ([*fit, str(t / "nonunit.npz")], "Observations.n: expected unit vectors"),
        "fit-obs-negative": ([*fit, str(t / "negative.npz")], "standard errors below 0; single values may be negative"),
        "fit-obs-source-list": ([*fit, str(t / "src_list.npz")], "source: expected a JSON object"),
        "fit-obs-source-bbox": ([*fit, str(t / "src_bbox.npz")], "source field 'bbox': expected"),
        "fit-obs-source-seed": ([*fit, str(t / "src_seed.npz")], "source field 'seed' must be a non-negative"),
        "fit-obs-source-object": ([*fit, str(t / "src_object.npz")], "source field 'object': TranslucentConfig"),
        "fit-obs-source-unknown": ([*fit, str(t / "src_extra.npz")], "unknown field(s) ['colour']"),
        "info-nbtf-label-type": (["data", "info", str(t / "label.nbtf")], "header field 'label' must be a string"),
        "layered-smudge-seed": (["data", "info", str(t / "smudge_seed.json")], "smudge_map seed: expected an integer"),
        "btf-directions-nan": (["data", "btf-generate", "procedural:bumps", "-o", str(t / "out.nbtf"), "--size", "8",
                                "--directions", "rings:3xnan"], "ring step must be a positive number"),
    }


def test_bad_files_and_settings_are_named_in_one_line(workdir):
    """Each case of `_checked_cases` fails with exit code 2 and an error line that says what was wrong."""
    runner = CliRunner()
    failures = []
    for name, (args, expected) in _checked_cases(workdir).items():
        r = runner.invoke(app, args)
        said = " ".join(r.output.split())
        if r.exit_code != 2 or expected not in said or "Traceback" in r.output:
            failures.append(f"{name}: exit code {r.exit_code}, expected {expected!r} in: {said[:400]}")
    assert not failures, "\n".join(failures)


@pytest.fixture
def workdir(tmp_path):
    (tmp_path / "out.png").write_bytes(PREVIOUS)
    (tmp_path / "out.nbtf").write_bytes(PREVIOUS)
    return tmp_path


def test_every_bad_command_line_is_a_clean_error(workdir):
    runner = CliRunner()
    failures = []
    for name, args in _bad_cases(workdir).items():
        before = _files(workdir)
        r = runner.invoke(app, args)
        said = " ".join(r.output.split())
        problems = []
        if r.exit_code not in (1, 2):
            problems.append(f"exit code {r.exit_code}")
        if r.exception is not None and not isinstance(r.exception, SystemExit):
            problems.append(f"raised {type(r.exception).__name__}: {r.exception}")
        if "Traceback" in r.output:
            problems.append("printed a traceback")
        after = _files(workdir)
        if after != before:
            problems.append(f"files changed: {sorted(set(after.items()) ^ set(before.items()))[:3]}")
        if problems:
            failures.append(f"{name} ({' '.join(args)}): {'; '.join(problems)}; said: {said[:300]}")
    assert not failures, "\n".join(failures)


def _neumat(args: list[str], timeout: float = 120) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": SRC}
    return subprocess.run([sys.executable, "-m", "neumat.cli.main", *args], env=env, capture_output=True,
                          text=True, timeout=timeout)


def test_bad_mesh_face_index_is_refused_not_a_crash(tmp_path):
    """A face pointing at vertex 99999 of 3 used to crash Mitsuba (SIGSEGV) or render garbage."""
    (tmp_path / "bad.ply").write_text(TRIANGLE.format(99999))
    for args in (["render", "lambert", "--scene", f"mesh:{tmp_path / 'bad.ply'}", "--resolution", "8",
                  "-o", str(tmp_path / "x.png")],
                 ["translucent", "trace", "-o", str(tmp_path / "o.npz"), "--scene", f"mesh:{tmp_path / 'bad.ply'}"]):
        r = _neumat(args)
        assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
        assert "vertex 99999" in " ".join(r.stderr.split())
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.ply"]


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this system")
def test_fifo_in_a_texture_set_is_refused_not_a_hang(tmp_path):
    folder = write_texture_set(tmp_path / "set", roughness=tmp_path)
    os.mkfifo(folder / "x_Roughness.png")
    r = _neumat(["render", str(folder), "--resolution", "8", "-o", str(tmp_path / "x.png")], timeout=60)
    assert r.returncode == 2 and "x_Roughness.png is not a regular file" in " ".join(r.stderr.split()), r.stderr
    assert not (tmp_path / "x.png").exists()


def test_failed_writes_leave_nothing_and_outputs_are_0644(tmp_path):
    from neumat.io.atomic import atomic_write
    from neumat.core.errors import InputError
    r = CliRunner().invoke(app, ["data", "btf-generate", "procedural:bumps", "-o", str(tmp_path / "b.nbtf"),
                                 "--size", "4", "--directions", "4", "--spp", "1"])
    assert r.exit_code == 0, r.output
    assert (tmp_path / "b.nbtf").stat().st_mode & 0o777 == 0o644 & ~_umask()
    (tmp_path / "dir.nmat").mkdir()
    with pytest.raises(InputError, match="is a folder"):
        atomic_write(tmp_path / "dir.nmat", lambda tmp: Path(tmp).write_bytes(b"x"))
    (tmp_path / "old.nmat").write_bytes(PREVIOUS)

    def broken(tmp):
        Path(tmp).write_bytes(b"half")
        raise OSError("disk full")
    with pytest.raises(OSError, match="disk full"):
        atomic_write(tmp_path / "old.nmat", broken)
    assert (tmp_path / "old.nmat").read_bytes() == PREVIOUS
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b.nbtf", "dir.nmat", "old.nmat"]


def test_outputs_into_missing_folders_are_written(tmp_path):
    """`fit -o missing/dir/x.nmat` failed after training (safetensors: 'No such file or directory'): outputs
    create their folder, as image outputs do."""
    from neumat.catalog.modelfile import load_model, save_model
    from neumat.models.registry import load_all
    save_model(load_all().get("ggx")(), tmp_path / "missing" / "dir" / "x.nmat")
    assert load_model(tmp_path / "missing" / "dir" / "x.nmat").name == "ggx"


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def test_texture_set_palette_and_cmyk_red_load_as_red(tmp_path):
    """Palette PNGs loaded as black and CMYK JPEGs as cyan: texture sets now decode every mode to RGB."""
    from PIL import Image
    from neumat.io.texture_set import load_texture_set
    for kind, save in (("palette", lambda im, p: im.convert("P").save(p.with_suffix(".png"))),
                       ("cmyk", lambda im, p: im.convert("CMYK").save(p.with_suffix(".jpg"), quality=100))):
        folder = write_texture_set(tmp_path / kind)
        (folder / "x_Color.png").unlink()
        save(Image.new("RGB", (4, 4), (255, 0, 0)), folder / "x_Color")
        color = load_texture_set(folder).color
        assert color[..., 0].min() > 0.9 and color[..., 1:].max() < 0.05, (kind, color[0, 0])


def test_nan_merl_table_is_not_written(tmp_path):
    from neumat.core.errors import InputError
    from neumat.io.merl import write_merl
    table = np.zeros((3, 90, 90, 180))
    table[0, 0, 0, :5] = np.nan
    with pytest.raises(InputError, match="5 of .* NaN or infinite"):
        write_merl(tmp_path / "x.binary", table)
    assert not list(tmp_path.iterdir())


def test_json_output_has_no_nan_or_infinity(tmp_path):
    r = CliRunner().invoke(app, ["compare", "lambert", "lambert", "--resolution", "8", "--spp", "1",
                                 "--n-configs", "64", "--json"])
    assert r.exit_code == 0, r.output
    assert "Infinity" not in r.stdout and "NaN" not in r.stdout
    json.loads(r.stdout, parse_constant=lambda c: pytest.fail(f"non-finite {c} in the JSON"))


def test_out_of_range_seed_and_missing_gpu_fail_before_work():
    for args in (["render", "lambert", "--seed", str(2 ** 70), "-o", "x.png"],
                 ["render", "lambert", "--device", "nonsense", "-o", "x.png"]):
        r = CliRunner().invoke(app, args)
        assert r.exit_code == 2 and not isinstance(r.exception, (ValueError, RuntimeError)), r.output
    if not torch.cuda.is_available():
        r = CliRunner().invoke(app, ["render", "lambert", "--device", "cuda", "-o", "x.png"])
        assert r.exit_code == 2 and "CUDA GPU" in " ".join(r.output.split()), r.output
