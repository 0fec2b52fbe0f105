"""MERL `.binary` I/O: bit-exact round trip, the reference byte layout, bad files, recognition by hash."""
from __future__ import annotations

import hashlib

import numpy as np
import pytest

from neumat import DataFormatError, InputError
from neumat.io.merl import MERL_DIMS, MERL_FILE_SIZE, identify_merl, read_merl, write_merl


@pytest.fixture(scope="module")
def table() -> np.ndarray:
    rng = np.random.default_rng(7)
    t = rng.lognormal(size=(3, *MERL_DIMS))
    t[0, 5, 6, 7] = -1.0  # a missing value survives the round trip
    return t


def test_round_trip_is_bit_exact(tmp_path, table):
    path = tmp_path / "a.binary"
    write_merl(path, table)
    assert path.stat().st_size == MERL_FILE_SIZE
    data = read_merl(path)
    assert data.dims == MERL_DIMS
    assert data.table.dtype == np.float64 and data.table.shape == (3, *MERL_DIMS)
    assert data.table.tobytes() == table.tobytes()
    write_merl(tmp_path / "b.binary", data.table)
    assert (tmp_path / "b.binary").read_bytes() == path.read_bytes()


def test_byte_layout_matches_brdfread(tmp_path):
    """BRDFRead.cpp: int32 dims, then red, green, blue blocks, each (theta_h, theta_d, phi_d) in C order."""
    c, i, j, k = np.meshgrid(*(np.arange(n) for n in (3, *MERL_DIMS)), indexing="ij")
    t = (c * 1e7 + i * 1e5 + j * 1e3 + k).astype(np.float64)
    path = tmp_path / "layout.binary"
    write_merl(path, t)
    raw = path.read_bytes()
    assert np.frombuffer(raw[:12], "<i4").tolist() == [90, 90, 180]
    for (cc, ii, jj, kk) in [(0, 0, 0, 1), (1, 2, 3, 4), (2, 89, 89, 179)]:
        ind = kk + jj * 180 + ii * 180 * 90 + cc * 90 * 90 * 180
        assert np.frombuffer(raw, "<f8", count=1, offset=12 + 8 * ind)[0] == cc * 1e7 + ii * 1e5 + jj * 1e3 + kk


def test_truncated_file(tmp_path, table):
    path = tmp_path / "t.binary"
    write_merl(path, table)
    path.write_bytes(path.read_bytes()[:-8])
    with pytest.raises(DataFormatError, match="bytes, expected"):
        read_merl(path)
    path.write_bytes(b"\x5a\0\0\0")
    with pytest.raises(DataFormatError, match="too short"):
        read_merl(path)


def test_wrong_header_and_size(tmp_path):
    path = tmp_path / "h.binary"
    path.write_bytes(np.array([90, 90, 360], "<i4").tobytes() + bytes(8 * 3 * 90 * 90 * 180))
    with pytest.raises(DataFormatError, match=r"header dimensions \(90, 90, 360\)"):
        read_merl(path)
    path.write_bytes(np.array([90, 90, 180], "<i4").tobytes() + bytes(8 * 3 * 90 * 90 * 180 + 8))
    with pytest.raises(DataFormatError, match="bytes, expected"):
        read_merl(path)
    with pytest.raises(InputError, match="does not exist"):
        read_merl(tmp_path / "missing.binary")


def test_write_rejects_bad_tables(tmp_path):
    with pytest.raises(InputError, match=r"expected shape \(3, 90, 90, 180\)"):
        write_merl(tmp_path / "x.binary", np.zeros((90, 90, 180)))
    with pytest.raises(InputError, match="floating-point"):
        write_merl(tmp_path / "x.binary", np.zeros((3, 90, 90, 180), dtype=np.int64))


def test_identify_by_size_and_hash(tmp_path, table):
    path = tmp_path / "m.binary"
    write_merl(path, table)
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    listing = tmp_path / "list.txt"
    listing.write_text(f"other.binary {'0' * 64} {MERL_FILE_SIZE}\nmy-metal.binary {digest} {MERL_FILE_SIZE}\n")
    assert identify_merl(path, hash_list=listing) == "my-metal"
    listing.write_text(f"other.binary {digest} 123\n")
    assert identify_merl(path, hash_list=listing) is None
    listing.write_text("garbage line\n")
    with pytest.raises(DataFormatError, match="line 1"):
        identify_merl(path, hash_list=listing)
    with pytest.raises(InputError, match="does not exist"):
        identify_merl(tmp_path / "none.binary", hash_list=listing)
    with pytest.raises(InputError, match="hash list .* does not exist"):
        identify_merl(path, hash_list=tmp_path / "none.txt")


def test_identify_with_the_shared_list(shared_data, tmp_path, table):
    """The shared list parses (100 entries) and a synthetic table is not a MERL material."""
    listing = shared_data / "merl" / "MERL100_sha256_from_git_lfs_pointers.txt"
    assert len([ln for ln in listing.read_text().splitlines() if ln.strip()]) == 100
    path = tmp_path / "m.binary"
    write_merl(path, table)
    assert identify_merl(path, hash_list=listing) is None
