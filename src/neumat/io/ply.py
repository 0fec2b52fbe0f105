"""Validate a PLY triangle mesh before Mitsuba reads it: Mitsuba trusts face indices, and one that points past
the vertex list crashes the process (SIGSEGV) or renders garbage.

`check_ply(path)` reads the header (ascii, binary_little_endian or binary_big_endian), checks the declared
sizes against the file size before reading any data, then checks that every face has 3 or 4 indices in
[0, vertex count) and that the vertex positions x, y, z are finite. It raises DataFormatError naming the file
and the problem.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..core.errors import DataFormatError, InputError

_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
          "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
          "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}
_MAX_HEADER = 1 << 16


def check_ply(path: str | Path) -> None:
    """Raise DataFormatError unless `path` is a readable PLY mesh with in-range face indices and finite
    vertex positions (see the module docstring); InputError when it is not a regular file."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"PLY mesh {str(path)!r}: expected an existing regular file")
    with open(path, "rb") as f:
        head = f.read(_MAX_HEADER)
    end = head.find(b"end_header")
    if not head.startswith(b"ply") or end < 0:
        raise DataFormatError(f"PLY mesh {path}: no 'ply ... end_header' header in its first {_MAX_HEADER} bytes")
    nl = head.find(b"\n", end)
    if nl < 0:
        raise DataFormatError(f"PLY mesh {path}: the header does not end with a newline")
    fmt, elements = _parse_header(path, head[:end].decode("ascii", "replace"))
    data = path.read_bytes()[nl + 1:]
    if fmt == "ascii":
        _check_ascii(path, data, elements)
    else:
        _check_binary(path, data, elements, "<" if fmt == "binary_little_endian" else ">")


def _parse_header(path: Path, text: str) -> tuple[str, list[dict]]:
    fmt, elements = None, []
    for line in text.splitlines()[1:]:
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        try:
            if words[0] == "format":
                fmt = words[1]
            elif words[0] == "element":
                elements.append({"name": words[1], "count": int(words[2]), "props": []})
            elif words[0] == "property" and words[1] == "list":
                elements[-1]["props"].append((words[4], _TYPES[words[2]], _TYPES[words[3]]))
            elif words[0] == "property":
                elements[-1]["props"].append((words[2], _TYPES[words[1]], None))
            else:
                raise ValueError
        except (IndexError, KeyError, ValueError):
            raise DataFormatError(f"PLY mesh {path}: malformed header line {line.strip()!r}") from None
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise DataFormatError(f"PLY mesh {path}: expected format ascii or binary_little/big_endian, got {fmt!r}")
    names = {e["name"]: e for e in elements}
    if "vertex" not in names or "face" not in names:
        raise DataFormatError(f"PLY mesh {path}: expected 'vertex' and 'face' elements, got {sorted(names)}")
    vprops = [p[0] for p in names["vertex"]["props"]]
    if not {"x", "y", "z"} <= set(vprops):
        raise DataFormatError(f"PLY mesh {path}: vertex needs properties x, y, z, got {vprops}")
    fprops = [p for p in names["face"]["props"] if p[2] is not None]
    if len(fprops) != 1 or fprops[0][0] not in ("vertex_indices", "vertex_index"):
        raise DataFormatError(f"PLY mesh {path}: face needs one list property vertex_indices")
    for e in elements:
        if e["count"] < 0 or (e["name"] in ("vertex", "face") and e["count"] == 0):
            raise DataFormatError(f"PLY mesh {path}: element {e['name']} has count {e['count']}, expected > 0")
        if e["count"] >= 2 ** 32:
            raise DataFormatError(f"PLY mesh {path}: element {e['name']} count {e['count']} exceeds 2^32 - 1")
    return fmt, elements


def _check_ascii(path: Path, data: bytes, elements: list[dict]) -> None:
    lines = data.split(b"\n")
    declared = sum(e["count"] for e in elements)
    rows = [ln for ln in lines if ln.strip()]
    if len(rows) < declared:
        raise DataFormatError(f"PLY mesh {path}: {declared} data rows declared, {len(rows)} present (truncated?)")
    at = 0
    for e in elements:
        block = rows[at:at + e["count"]]
        at += e["count"]
        if e["name"] == "vertex":
            names = [p[0] for p in e["props"]]
            v = _parse(path, e, lambda: np.array([ln.split()[:len(names)] for ln in block], dtype=np.float64))
            if v.shape != (e["count"], len(names)):
                raise DataFormatError(f"PLY mesh {path}: vertex rows need {len(names)} numbers each")
            _check_vertices(path, v[:, [names.index(c) for c in "xyz"]])
        elif e["name"] == "face":
            faces = _parse(path, e, lambda: [[int(w) for w in ln.split()] for ln in block])
            if any(not f or f[0] != len(f) - 1 for f in faces):
                raise DataFormatError(f"PLY mesh {path}: a face row's first number is not its index count")
            _check_faces(path, [f[1:] for f in faces], _vertex_count(elements))


def _parse(path: Path, element: dict, read):
    try:
        return read()
    except ValueError:
        raise DataFormatError(f"PLY mesh {path}: malformed {element['name']} rows") from None


def _check_binary(path: Path, data: bytes, elements: list[dict], order: str) -> None:
    offset = 0
    for e in elements:
        fixed = [p for p in e["props"] if p[2] is None]
        if all(p[2] is None for p in e["props"]):
            dtype = np.dtype([(f"p{i}", order + t) for i, (_, t, _) in enumerate(fixed)])
            need = dtype.itemsize * e["count"]
            if offset + need > len(data):
                raise DataFormatError(f"PLY mesh {path}: element {e['name']} declares {e['count']} rows "
                                      f"({need} bytes), only {len(data) - offset} bytes left (truncated?)")
            rows = np.frombuffer(data, dtype, e["count"], offset)
            if e["name"] == "vertex":
                names = [p[0] for p in e["props"]]
                _check_vertices(path, np.stack([rows[f"p{names.index(c)}"].astype(np.float64) for c in "xyz"], 1))
            offset += need
        elif e["name"] == "face" and len(e["props"]) == 1:
            _, count_t, index_t = e["props"][0]
            faces, offset = _read_faces(path, data, offset, e["count"], order + count_t, order + index_t)
            _check_faces(path, faces, _vertex_count(elements))
        else:
            raise DataFormatError(f"PLY mesh {path}: element {e['name']} with list properties is not supported")


def _read_faces(path: Path, data: bytes, offset: int, count: int, count_t: str, index_t: str):
    """Faces stored as (n, i_1 .. i_n) rows: vectorised when every n equals the first, as in triangle meshes."""
    ct, it = np.dtype(count_t), np.dtype(index_t)
    if offset + ct.itemsize > len(data):
        raise DataFormatError(f"PLY mesh {path}: face data is missing (truncated?)")
    n = int(np.frombuffer(data, ct, 1, offset)[0])
    row = np.dtype([("n", ct), ("i", it, (max(n, 1),))])
    if offset + row.itemsize * count <= len(data):
        rows = np.frombuffer(data, row, count, offset)
        if (rows["n"] == n).all():
            return rows["i"][:, :n].astype(np.int64), offset + row.itemsize * count
    faces = []
    for _ in range(count):
        if offset + ct.itemsize > len(data):
            raise DataFormatError(f"PLY mesh {path}: {count} faces declared, {len(faces)} present (truncated?)")
        k = int(np.frombuffer(data, ct, 1, offset)[0])
        offset += ct.itemsize
        if offset + k * it.itemsize > len(data):
            raise DataFormatError(f"PLY mesh {path}: {count} faces declared, {len(faces)} present (truncated?)")
        faces.append(np.frombuffer(data, it, k, offset).astype(np.int64).tolist())
        offset += k * it.itemsize
    return faces, offset


def _vertex_count(elements: list[dict]) -> int:
    return next(e["count"] for e in elements if e["name"] == "vertex")


def _check_vertices(path: Path, xyz: np.ndarray) -> None:
    bad = ~np.isfinite(xyz).all(1)
    if bad.any():
        raise DataFormatError(f"PLY mesh {path}: {int(bad.sum())} vertex position(s) are NaN or infinite "
                              f"(first: vertex {int(np.argmax(bad))})")


def _check_faces(path: Path, faces, nvert: int) -> None:
    if isinstance(faces, np.ndarray):
        sizes, flat = np.full(len(faces), faces.shape[1]), faces.reshape(-1)
    else:
        sizes = np.array([len(f) for f in faces])
        flat = np.array([i for f in faces for i in f], dtype=np.int64)
    if ((sizes < 3) | (sizes > 4)).any():
        k = int(np.argmax((sizes < 3) | (sizes > 4)))
        raise DataFormatError(f"PLY mesh {path}: face {k} has {int(sizes[k])} vertices, expected 3 or 4")
    bad = (flat < 0) | (flat >= nvert)
    if bad.any():
        i = int(np.argmax(bad))
        raise DataFormatError(f"PLY mesh {path}: a face points at vertex {int(flat[i])}, expected an index in "
                              f"[0, {nvert}) ({int(bad.sum())} such index(es))")
