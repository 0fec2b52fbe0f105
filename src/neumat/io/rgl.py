"""RGL material database files (Dupuy & Jakob 2018): Mitsuba `tensor_file` containers (`*_rgb.bsdf`).

Container layout (little endian): magic ``b"tensor_file\\0"``, version (uint8 1, uint8 0), uint32 field
count, then per field: uint16 name length, name, uint16 ndim, uint8 dtype code, uint64 data offset,
ndim x uint64 shape; the data of each field is a C-order array at its offset.
"""
from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.errors import DataFormatError, InputError

MAGIC = b"tensor_file\0"
#: Mitsuba `Struct` type codes used by tensor files
DTYPES = {1: np.uint8, 2: np.int8, 3: np.uint16, 4: np.int16, 5: np.uint32, 6: np.int32,
          7: np.uint64, 8: np.int64, 9: np.float16, 10: np.float32, 11: np.float64}
#: most negative rgb value accepted, relative to the table's maximum: the RGL database stores small negative
#: values (measurement noise, down to -1.4 % of the maximum in the shared files), kept as Mitsuba keeps them;
#: a table beyond this is refused as broken
NEGATIVE_RGB_LIMIT = 0.1
#: fields the `measured` BSDF needs in an RGB file
RGL_FIELDS = ("theta_i", "phi_i", "ndf", "sigma", "vndf", "luminance", "rgb", "description", "jacobian")


@dataclass
class RglData:
    """A parsed RGL BRDF.

    fields:      every field of the file as a numpy array (float32 tables, uint8 text/flags).
                 Shapes: theta_i (T,), phi_i (P,), ndf and sigma (Hn, Wn), vndf (P, T, Hv, Wv),
                 luminance (P, T, R, R), rgb (P, T, 3, R, R), jacobian (1,).
    description: the `description` field as text.
    """

    fields: dict[str, np.ndarray]
    description: str

    @property
    def isotropic(self) -> bool:
        """True when the file stores at most two incident azimuths (Mitsuba's rule)."""
        return self.fields["phi_i"].shape[0] <= 2


def read_tensor_file(path: str | Path) -> dict[str, np.ndarray]:
    """All fields of a Mitsuba tensor file as numpy arrays; DataFormatError on a malformed file."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"tensor file {path}: does not exist")
    raw = path.read_bytes()
    if raw[:12] != MAGIC:
        raise DataFormatError(f"tensor file {path}: wrong magic {raw[:12]!r}, expected {MAGIC!r}")
    pos = 12

    def take(fmt: str):
        nonlocal pos
        size = struct.calcsize(fmt)
        if pos + size > len(raw):
            raise DataFormatError(f"tensor file {path}: truncated header at byte {pos} ({len(raw)} bytes)")
        out = struct.unpack_from(fmt, raw, pos)
        pos += size
        return out

    version = take("<BB")
    if version != (1, 0):
        raise DataFormatError(f"tensor file {path}: version {version}, expected (1, 0)")
    (count,) = take("<I")
    headers = []
    for _ in range(count):
        (name_len,) = take("<H")
        name = bytes(take(f"<{name_len}s")[0]).decode("utf8", errors="replace")
        (ndim,) = take("<H")
        (code,) = take("<B")
        (offset,) = take("<Q")
        shape = take(f"<{ndim}Q") if ndim else ()
        if code not in DTYPES:
            raise DataFormatError(f"tensor file {path}: field {name!r} has unknown dtype code {code}")
        headers.append((name, np.dtype(DTYPES[code]).newbyteorder("<"), offset, tuple(int(s) for s in shape)))
    fields = {}
    for name, dtype, offset, shape in headers:
        nbytes = math.prod(shape) * dtype.itemsize  # Python ints: a huge declared shape cannot overflow
        if offset + nbytes > len(raw):
            raise DataFormatError(f"tensor file {path}: field {name!r} needs bytes {offset}..{offset + nbytes}, "
                                  f"but the file has {len(raw)} (truncated)")
        fields[name] = np.frombuffer(raw, dtype=dtype, count=nbytes // dtype.itemsize,
                                     offset=offset).reshape(shape).copy()
    return fields


def write_tensor_file(path: str | Path, fields: dict[str, np.ndarray], align: int = 8) -> None:
    """Write numpy arrays (or str, stored as uint8) as a Mitsuba tensor file, data aligned to `align` bytes."""
    codes = {np.dtype(t): c for c, t in DTYPES.items()}
    arrays = {}
    for name, v in fields.items():
        a = np.frombuffer(v.encode("utf8"), dtype=np.uint8) if isinstance(v, str) else np.ascontiguousarray(v)
        if a.dtype.newbyteorder("=") not in codes:
            raise InputError(f"write_tensor_file field {name!r}: unsupported dtype {a.dtype}")
        arrays[name] = a.astype(a.dtype.newbyteorder("<"), copy=False)
    header = bytearray(MAGIC + struct.pack("<BBI", 1, 0, len(arrays)))
    header_size = len(header) + sum(2 + len(n.encode()) + 2 + 1 + 8 + 8 * a.ndim for n, a in arrays.items())
    body, pos = bytearray(), header_size
    for name, a in arrays.items():
        start = (pos + align - 1) // align * align
        body += b"\0" * (start - pos) + a.tobytes()
        pos = start + a.nbytes
        label = name.encode("utf8")
        header += struct.pack("<H", len(label)) + label + struct.pack("<HBQ", a.ndim, codes[a.dtype.newbyteorder("=")],
                                                                     start)
        header += struct.pack(f"<{a.ndim}Q", *a.shape)
    Path(path).write_bytes(bytes(header) + bytes(body))


def read_rgl(path: str | Path) -> RglData:
    """Read an RGL `*_rgb.bsdf` file and check the structure the `measured` BSDF expects."""
    fields = read_tensor_file(path)
    missing = [k for k in RGL_FIELDS if k not in fields]
    if missing:
        raise DataFormatError(f"RGL file {path}: missing field(s) {', '.join(missing)} "
                              f"(an RGB measured BRDF needs {', '.join(RGL_FIELDS)})")
    f = fields
    n_phi, n_theta = f["phi_i"].shape[0] if f["phi_i"].ndim == 1 else -1, \
        f["theta_i"].shape[0] if f["theta_i"].ndim == 1 else -1
    checks = [
        ("theta_i", f["theta_i"].ndim == 1 and f["theta_i"].dtype == np.float32, "float32 (T,)"),
        ("phi_i", f["phi_i"].ndim == 1 and f["phi_i"].dtype == np.float32, "float32 (P,)"),
        ("ndf", f["ndf"].ndim == 2 and f["ndf"].dtype == np.float32 and min(f["ndf"].shape) >= 2,
         "float32 (H, W), H, W >= 2"),
        ("sigma", f["sigma"].ndim == 2 and f["sigma"].dtype == np.float32 and min(f["sigma"].shape) >= 2,
         "float32 (H, W), H, W >= 2"),
        ("vndf", f["vndf"].ndim == 4 and f["vndf"].dtype == np.float32 and f["vndf"].shape[:2] == (n_phi, n_theta)
         and min(f["vndf"].shape[2:]) >= 2, "float32 (P, T, H, W)"),
        ("luminance", f["luminance"].ndim == 4 and f["luminance"].dtype == np.float32
         and f["luminance"].shape[:2] == (n_phi, n_theta) and f["luminance"].shape[2] == f["luminance"].shape[3]
         and f["luminance"].shape[2] >= 2, "float32 (P, T, R, R)"),
        ("rgb", f["rgb"].ndim == 5 and f["rgb"].dtype == np.float32
         and f["rgb"].shape[:3] == (n_phi, n_theta, 3) and f["rgb"].shape[3:] == f["luminance"].shape[2:],
         "float32 (P, T, 3, R, R) matching luminance"),
        ("description", f["description"].ndim == 1 and f["description"].dtype == np.uint8, "uint8 (n,)"),
        ("jacobian", f["jacobian"].shape == (1,) and f["jacobian"].dtype == np.uint8, "uint8 (1,)"),
    ]
    for name, ok, expected in checks:
        if not ok:
            raise DataFormatError(f"RGL file {path}: field {name!r} is {f[name].dtype} {f[name].shape}, "
                                  f"expected {expected}")
    _check_values(path, f)
    desc = f["description"].tobytes().decode("utf8", errors="replace").rstrip("\0")
    return RglData(fields=fields, description=desc)


def _check_values(path, f: dict[str, np.ndarray]) -> None:
    """Refuse values the `measured` BSDF cannot use: non-finite numbers, incident angles out of order or range,
    negative or all-zero densities (a VNDF or luminance slice with no mass cannot be sampled), sigma <= 0 (a
    divisor), an rgb table with no positive value or negative values beyond NEGATIVE_RGB_LIMIT."""
    def fail(name: str, problem: str):
        raise DataFormatError(f"RGL file {path}: field {name!r} {problem}")

    for name in ("theta_i", "phi_i", "ndf", "sigma", "vndf", "luminance", "rgb"):
        bad = int((~np.isfinite(f[name])).sum())
        if bad:
            fail(name, f"has {bad} NaN or infinite value(s); expected finite numbers")
    theta, phi = f["theta_i"], f["phi_i"]
    if (np.diff(theta) <= 0).any() or theta[0] < 0 or theta[-1] > np.float32(math.pi / 2):
        fail("theta_i", f"is {np.array2string(theta, precision=4, threshold=8)}; expected strictly ascending "
                        "incident elevations in [0, pi/2]")
    if (np.diff(phi) <= 0).any():
        fail("phi_i", f"is {np.array2string(phi, precision=4, threshold=8)}; expected strictly ascending azimuths")
    for name in ("ndf", "vndf", "luminance"):
        if (f[name] < 0).any():
            fail(name, f"has negative values (min {f[name].min():.4g}); expected a density >= 0")
    for name in ("vndf", "luminance"):
        empty = np.argwhere(f[name].sum(axis=(2, 3)) <= 0)
        if len(empty):
            p, t = empty[0]
            fail(name, f"is zero everywhere for incident direction (phi_i[{p}], theta_i[{t}]) "
                       f"({len(empty)} such slice(s)); expected a density with positive mass")
    if not (f["ndf"] > 0).any():
        fail("ndf", "is zero everywhere; expected a density with positive mass")
    if (f["sigma"] <= 0).any():
        fail("sigma", f"has values <= 0 (min {f['sigma'].min():.4g}); expected positive projected areas")
    rgb = f["rgb"]
    top, low = float(rgb.max()), float(rgb.min())
    if top <= 0:
        fail("rgb", f"has no positive value (max {top:.4g}); expected reflectance values > 0")
    if low < -NEGATIVE_RGB_LIMIT * top:
        fail("rgb", f"has values down to {low:.4g}, beyond -{NEGATIVE_RGB_LIMIT:g} x its maximum {top:.4g}; "
                    "expected non-negative reflectance (small negative noise is kept)")
