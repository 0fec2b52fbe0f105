"""`check_ply`: PLY meshes are checked before Mitsuba reads them (a bad face index used to crash the process)."""
from __future__ import annotations

import numpy as np
import pytest

from neumat.core.errors import DataFormatError, InputError
from neumat.io.ply import check_ply

HEADER = ("ply\nformat {fmt} 1.0\nelement vertex {nv}\nproperty float x\nproperty float y\nproperty float z\n"
          "element face {nf}\nproperty list uchar int vertex_indices\nend_header\n")


def ascii_ply(path, verts="0 0 0\n1 0 0\n0 1 0\n", faces="3 0 1 2\n", nv=3, nf=1):
    path.write_text(HEADER.format(fmt="ascii", nv=nv, nf=nf) + verts + faces)
    return path


def binary_ply(path, verts, faces, order="<", nv=None, nf=None, cut=0):
    v = np.asarray(verts, dtype=order + "f4").tobytes()
    rows = np.zeros(len(faces), np.dtype([("n", "u1"), ("i", order + "i4", (3,))]))
    rows["n"], rows["i"] = 3, faces
    fmt = "binary_little_endian" if order == "<" else "binary_big_endian"
    data = HEADER.format(fmt=fmt, nv=len(verts) if nv is None else nv, nf=len(faces) if nf is None else nf).encode()
    body = v + rows.tobytes()
    path.write_bytes(data + body[:len(body) - cut])
    return path


TRI = [[0, 0, 0], [1, 0, 0], [0, 1, 0]]


def test_good_meshes_pass(tmp_path, shared_data):
    check_ply(ascii_ply(tmp_path / "a.ply"))
    check_ply(binary_ply(tmp_path / "b.ply", TRI, [[0, 1, 2]]))
    check_ply(binary_ply(tmp_path / "c.ply", TRI, [[0, 1, 2]], order=">"))
    for mesh in sorted((shared_data / "mesh").glob("*.ply")):
        check_ply(mesh)


@pytest.mark.parametrize("make, message", [
    (lambda p: ascii_ply(p, faces="3 0 1 99999\n"), "vertex 99999, expected an index in \\[0, 3\\)"),
    (lambda p: ascii_ply(p, faces="3 0 -1 2\n"), "vertex -1"),
    (lambda p: ascii_ply(p, faces="2 0 1\n"), "face 0 has 2 vertices"),
    (lambda p: ascii_ply(p, faces="4 0 1 2\n"), "first number is not its index count"),
    (lambda p: ascii_ply(p, verts="0 0 0\nnan 0 0\n0 1 0\n"), "NaN or infinite"),
    (lambda p: ascii_ply(p, verts="0 0 0\n1 zero 0\n0 1 0\n"), "malformed vertex rows"),
    (lambda p: ascii_ply(p, nf=5), "5 data rows declared|6 data rows declared|truncated"),
    (lambda p: ascii_ply(p, nv=0, verts=""), "vertex has count 0"),
    (lambda p: binary_ply(p, TRI, [[0, 1, 99999]]), "vertex 99999"),
    (lambda p: binary_ply(p, TRI, [[0, 1, 99999]], order=">"), "vertex 99999"),
    (lambda p: binary_ply(p, TRI, [[0, 1, 2]], cut=3), "truncated"),
    (lambda p: binary_ply(p, TRI, [[0, 1, 2]], nv=10 ** 12), "truncated|exceeds"),
    (lambda p: binary_ply(p, TRI, [[0, 1, 2]], nf=10 ** 9), "truncated"),
    (lambda p: binary_ply(p, [[0, 0, 0], [np.inf, 0, 0], [0, 1, 0]], [[0, 1, 2]]), "NaN or infinite"),
    (lambda p: p.write_bytes(b""), "header"),
    (lambda p: p.write_bytes(b"ply\nformat ascii 1.0\nend_header\n"), "'vertex' and 'face'"),
    (lambda p: p.write_bytes(b"ply\nformat nonsense 1.0\nelement vertex 1\nend_header\n"), "format"),
    (lambda p: p.write_bytes(b"ply\nformat ascii 1.0\nelement vertex many\nend_header\n"), "malformed header"),
    (lambda p: p.write_bytes(b"ply\nformat ascii 1.0\nproperty float x\nend_header\n"), "malformed header"),
])
def test_bad_meshes_are_refused_with_the_reason(tmp_path, make, message):
    path = tmp_path / "bad.ply"
    make(path)
    with pytest.raises(DataFormatError, match=message):
        check_ply(path)


def test_not_a_file(tmp_path):
    with pytest.raises(InputError, match="regular file"):
        check_ply(tmp_path)
