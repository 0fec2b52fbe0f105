"""MERL BRDF files (`.binary`, Matusik et al. 2003): read, write, recognise.

Layout (reference `BRDFRead.cpp`): three little-endian int32 dimensions (90, 90, 180), then
3 * 90 * 90 * 180 float64 values: all red, then all green, then all blue, each in C order over
(theta_half, theta_diff, phi_diff). Values are unscaled; the lookup multiplies them by `MERL_SCALE`.
Negative values (-1) mark missing measurements.
"""
from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.errors import DataFormatError, InputError
from .atomic import atomic_write

#: table resolution (theta_half, theta_diff, phi_diff)
MERL_DIMS = (90, 90, 180)
#: per-channel factors (R, G, B) applied at lookup time
MERL_SCALE = (1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0)
#: file size in bytes: 3 int32 + 3 * 90 * 90 * 180 float64
MERL_FILE_SIZE = 12 + 3 * 90 * 90 * 180 * 8
#: default list of the 100 MERL files' names, sha256 and sizes
MERL_HASH_LIST = Path(__file__).resolve().parents[4] / "shared" / "data" / "merl" / \
    "MERL100_sha256_from_git_lfs_pointers.txt"


@dataclass
class MerlData:
    """A MERL table.

    table: (3, 90, 90, 180) float64, channels R, G, B over (theta_half, theta_diff, phi_diff), unscaled.
    dims:  the three dimensions from the file header.
    """

    table: np.ndarray
    dims: tuple[int, int, int]


def read_merl(path: str | Path) -> MerlData:
    """Read a MERL `.binary` file; DataFormatError when truncated, its header is not 90 90 180, a value is NaN or
    infinite, or every value is missing (negative)."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"MERL file {path}: does not exist")
    raw = path.read_bytes()
    if len(raw) < 12:
        raise DataFormatError(f"MERL file {path}: {len(raw)} bytes, too short for the 12-byte header")
    dims = tuple(int(d) for d in np.frombuffer(raw[:12], dtype="<i4"))
    if dims != MERL_DIMS:
        raise DataFormatError(f"MERL file {path}: header dimensions {dims}, expected {MERL_DIMS}")
    if len(raw) != MERL_FILE_SIZE:
        raise DataFormatError(f"MERL file {path}: {len(raw)} bytes, expected {MERL_FILE_SIZE} "
                              f"(12-byte header + 3 x 90 x 90 x 180 float64)")
    table = np.frombuffer(raw, dtype="<f8", offset=12).reshape(3, *MERL_DIMS).astype(np.float64)
    bad = int((~np.isfinite(table)).sum())
    if bad:
        raise DataFormatError(f"MERL file {path}: {bad} of {table.size} values are NaN or infinite; expected finite "
                              "values (negative ones mark missing measurements)")
    if not (table >= 0).any():
        raise DataFormatError(f"MERL file {path}: every value is negative (missing); expected measured values >= 0")
    return MerlData(table=table, dims=dims)


def write_merl(path: str | Path, table: np.ndarray) -> None:
    """Write an unscaled (3, 90, 90, 180) table (R, G, B) as a MERL `.binary` file."""
    table = np.asarray(table)
    if table.shape != (3, *MERL_DIMS):
        raise InputError(f"write_merl table: expected shape (3, 90, 90, 180), got {table.shape}")
    if not np.issubdtype(table.dtype, np.floating):
        raise InputError(f"write_merl table: expected a floating-point array, got {table.dtype}")
    bad = int((~np.isfinite(table)).sum())
    if bad:
        raise InputError(f"write_merl table: {bad} of {table.size} values are NaN or infinite (a broken source "
                         "material?); expected finite values")
    data = np.asarray(MERL_DIMS, dtype="<i4").tobytes() + np.ascontiguousarray(table, dtype="<f8").tobytes()
    atomic_write(path, lambda tmp: Path(tmp).write_bytes(data))


def identify_merl(path: str | Path, hash_list: str | Path = MERL_HASH_LIST) -> str | None:
    """Name of the MERL material (e.g. ``"alum-bronze"``) whose size and sha256 match the file, else None.

    `hash_list` has one ``name.binary sha256 size`` line per material.
    """
    path, hash_list = Path(path), Path(hash_list)
    if not path.is_file():
        raise InputError(f"MERL file {path}: does not exist")
    if not hash_list.is_file():
        raise InputError(f"MERL hash list {hash_list}: does not exist")
    size = path.stat().st_size
    known = {}
    for n, line in enumerate(hash_list.read_text().splitlines(), 1):
        if not line.strip():
            continue
        parts = line.split()
        if len(parts) != 3 or not parts[2].isdigit():
            raise DataFormatError(f"MERL hash list {hash_list} line {n}: expected 'name sha256 size', got {line!r}")
        known[(parts[1].lower(), int(parts[2]))] = parts[0].removesuffix(".binary")
    if not any(s == size for _, s in known):
        return None
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    return known.get((digest, size))
