"""RGL tensor files: parsing every field of the shared files, writing, and malformed-file errors."""
from __future__ import annotations

import numpy as np
import pytest

from neumat import DataFormatError, InputError
from neumat.io.rgl import RGL_FIELDS, read_rgl, read_tensor_file, write_tensor_file

from mitsuba_util import mitsuba_or_skip


@pytest.fixture
def rgl_files(shared_data):
    files = sorted((shared_data / "rgl").glob("*_rgb.bsdf"))
    if not files:
        pytest.skip("no RGL *_rgb.bsdf files in the shared data folder")
    return files


def test_shared_files_parse(rgl_files):
    for path in rgl_files:
        d = read_rgl(path)
        f = d.fields
        assert set(RGL_FIELDS) <= set(f)
        assert d.isotropic and f["phi_i"].shape == (1,)
        n_theta = f["theta_i"].shape[0]
        assert f["vndf"].shape[:2] == (1, n_theta) and f["rgb"].shape[:3] == (1, n_theta, 3)
        assert np.all(np.diff(f["theta_i"]) > 0) and f["theta_i"][-1] == pytest.approx(np.pi / 2)
        assert len(d.description) > 3 and d.description.isprintable()
        assert f["jacobian"].tolist() in ([0], [1])


def test_write_read_round_trip(tmp_path):
    rng = np.random.default_rng(3)
    fields = {"a": rng.normal(size=(2, 3, 4)).astype(np.float32), "b": np.arange(5, dtype=np.uint8),
              "c": rng.normal(size=7), "d": np.array([1, -2], dtype=np.int16), "text": "hello"}
    path = tmp_path / "x.bsdf"
    write_tensor_file(path, fields)
    out = read_tensor_file(path)
    assert list(out) == list(fields)
    for k, v in fields.items():
        expect = np.frombuffer(v.encode(), np.uint8) if isinstance(v, str) else v
        assert out[k].dtype == expect.dtype and np.array_equal(out[k], expect)


def test_round_trip_of_a_shared_file(rgl_files, tmp_path):
    fields = read_tensor_file(rgl_files[0])
    write_tensor_file(tmp_path / "copy.bsdf", fields)
    again = read_tensor_file(tmp_path / "copy.bsdf")
    assert all(np.array_equal(fields[k], again[k]) for k in fields)


def _small_file(path, drop=(), **override):
    rng = np.random.default_rng(0)
    fields = {"description": "test", "phi_i": np.zeros(1, np.float32),
              "theta_i": np.linspace(0, np.pi / 2, 3, dtype=np.float32),
              "ndf": rng.random((2, 8), dtype=np.float32), "sigma": rng.random((2, 8), dtype=np.float32),
              "vndf": rng.random((1, 3, 8, 8), dtype=np.float32),
              "luminance": rng.random((1, 3, 4, 4), dtype=np.float32),
              "rgb": rng.random((1, 3, 3, 4, 4), dtype=np.float32), "jacobian": np.ones(1, np.uint8)}
    fields.update(override)
    write_tensor_file(path, {k: v for k, v in fields.items() if k not in drop})
    return path


def test_missing_field(tmp_path):
    read_rgl(_small_file(tmp_path / "ok.bsdf"))
    with pytest.raises(DataFormatError, match="missing field.*vndf"):
        read_rgl(_small_file(tmp_path / "m.bsdf", drop=("vndf",)))


def test_wrong_field_shape(tmp_path):
    bad = np.zeros((1, 2, 3, 4, 4), np.float32)
    with pytest.raises(DataFormatError, match="field 'rgb'"):
        read_rgl(_small_file(tmp_path / "s.bsdf", rgb=bad))


def test_wrong_magic_version_truncation(tmp_path):
    good = _small_file(tmp_path / "g.bsdf").read_bytes()
    path = tmp_path / "bad.bsdf"
    path.write_bytes(b"tensor_fil3\0" + good[12:])
    with pytest.raises(DataFormatError, match="wrong magic"):
        read_tensor_file(path)
    path.write_bytes(good[:12] + b"\x02\x00" + good[14:])
    with pytest.raises(DataFormatError, match="version"):
        read_tensor_file(path)
    path.write_bytes(good[:40])
    with pytest.raises(DataFormatError, match="truncated header"):
        read_tensor_file(path)
    path.write_bytes(good[:-16])
    with pytest.raises(DataFormatError, match="truncated"):
        read_tensor_file(path)
    with pytest.raises(InputError, match="does not exist"):
        read_tensor_file(tmp_path / "none.bsdf")


@pytest.mark.mitsuba
def test_matches_mitsuba_reader(rgl_files):
    """Field for field, our parser agrees with `mitsuba.python.tensor_io.read`."""
    mitsuba_or_skip()
    from mitsuba.python import tensor_io
    import contextlib
    import io
    for path in rgl_files:
        with contextlib.redirect_stdout(io.StringIO()):
            ref = tensor_io.read(str(path))
        ours = read_tensor_file(path)
        assert list(ours) == list(ref)
        assert all(ours[k].dtype == ref[k].dtype and np.array_equal(ours[k], ref[k]) for k in ref)
