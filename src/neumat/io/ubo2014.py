"""Reader for the Bonn BTF database files (UBO2014 and other Bonn `.btf` files in the (D)FMF formats).

Layout (learned from the University of Bonn's btflib, https://github.com/cgbonn/btflib, LGPL: files
``matlab/@btf/private/{ubo_btf_signatures,read_ubo_dfmf,read_ubo_fmf,read_common_header,read_meta_data,
read_bidir_sampling,undecorrelate,restore_dynamic_range,decode_dfmf_texture,decode_fmf_texture,
write_ubo_dfmf,write_ubo_fmf}.m`` and ``matlab/utils/fread_matrix.m``; cross-checked with the C++ reader
``btf_extractor/c_ext/btf.hh`` of https://github.com/2-propanol/BTF_extractor, the code behind the
`btf-extractor` package). This module is an independent implementation of that layout. All numbers are
little-endian; matrices are stored row-major.

Details: docs/formats/ubo2014.md, section `neumat.io.ubo2014`.
"""
from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from ..core.errors import DataFormatError, InputError
from .btf import BTFTable

#: signature -> (variant, has the FMF extended header); the trailing "R" announces the rotation block
SIGNATURES = {b"!DFMF08FCR": ("DFMF", False), b"!FMF12FCER": ("FMF", True),
              b"!FMF06FCR": ("FMF", False), b"!FMF06FC": ("FMF", False)}
#: Bonn formats this reader refuses (per-view PCA, raw image tiles)
UNSUPPORTED_SIGNATURES = {b"!PVF06FCR": "PVF (per-view factorisation)", b"!PVF06FC": "PVF (per-view factorisation)",
                          b"!BDIF06R2!": "BDI (uncompressed image chunks)"}
#: colour models `read_ubo2014` can undo
COLOR_MODELS = {0: "RGB", 1: "YUV", 3: "PCA", 4: "YCoCg", 9: "log(Y) U V", 10: "log(Y) log(U) log(V)",
                11: "log(Y) U/Y V/Y", 12: "log(RGB)"}
#: additive offset of the logarithmic colour models and of the dynamic-range reduction
DRR_EPS = 1e-5
YUV_TO_RGB = ((1.0, 0.0, 1.13983), (1.0, -0.39465, -0.5806), (1.0, 2.03211, 0.0))
YCOCG_TO_RGB = ((1.0, 1.0, -1.0), (1.0, 0.0, 1.0), (1.0, -1.0, -1.0))
_SCALAR_TYPES = {2: np.dtype("<f2"), 4: np.dtype("<f4"), 8: np.dtype("<f8")}


@dataclass(frozen=True)
class FactorRows:
    """Rows `offset + index * stride` of a stored (rows x components) matrix starting at byte `start`."""

    start: int
    rows: int
    components: int
    dtype: np.dtype
    offset: int = 0
    stride: int = 1

    def load(self, path: Path, index: np.ndarray, k: int) -> torch.Tensor:
        """Float32 tensor (len(index), k): the first k components of the selected rows."""
        matrix = np.memmap(path, self.dtype, "r", self.start, (self.rows, self.components))
        return torch.from_numpy(np.asarray(matrix[self.offset + index * self.stride, :k], dtype=np.float32))


@dataclass(frozen=True)
class ChannelFactors:
    """One decorrelated channel: value[lv, xy] = sum_k angular[lv, k] spatial[xy, k] over `components`."""

    angular: FactorRows
    spatial: FactorRows
    components: int


@dataclass(frozen=True, eq=False)
class Ubo2014Header:
    """Everything but the factor matrices. Angles in radians, (n, 2) = (theta, phi) per direction."""

    path: Path
    signature: str
    variant: str                 # "DFMF" or "FMF"
    width: int
    height: int
    light_angles: np.ndarray     # (L, 2)
    view_angles: np.ndarray      # (V, 2)
    channel_names: tuple[str, ...]
    cosine_flag: bool
    color_model: int
    color_mean: np.ndarray       # (3,)
    color_matrix: np.ndarray     # (3, 3)
    dynamic_range_reduction: bool
    scalar_size: int
    measurement_setup: str
    ppmm: float
    xml: str
    channels: tuple[ChannelFactors, ...] = field(repr=False)

    @property
    def components(self) -> tuple[int, ...]:
        """Stored SVD components per channel."""
        return tuple(c.components for c in self.channels)

    def light_dirs(self) -> torch.Tensor:
        """(L, 3) unit vectors towards the lights (wi)."""
        return angles_to_directions(self.light_angles)

    def view_dirs(self) -> torch.Tensor:
        """(V, 3) unit vectors towards the camera (wo)."""
        return angles_to_directions(self.view_angles)


def angles_to_directions(angles: np.ndarray) -> torch.Tensor:
    """(n, 3) float32 unit vectors from (n, 2) polar angles theta and azimuths phi in radians."""
    a = torch.as_tensor(np.asarray(angles, dtype=np.float64))
    st = a[:, 0].sin()
    return torch.stack([st * a[:, 1].cos(), st * a[:, 1].sin(), a[:, 0].cos()], -1).float()


def read_ubo2014_header(path: str | Path) -> Ubo2014Header:
    """Parse and validate the header and factor layout of a Bonn `.btf` file (reads no factor data)."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"UBO2014 file {str(path)!r} does not exist")
    with open(path, "rb") as f:
        return _HeaderParser(path, f, path.stat().st_size).parse()


def read_ubo2014_table(path: str | Path, texels: tuple[int, int, int, int] | None = None, step: int = 1,
                       max_components: int | None = None, device=None, max_gib: float = 8.0) -> BTFTable:
    """A `BTFTable` (L, V, h, w, 3) decoded from a Bonn `.btf` file (UBO2014 archive: DFMF); the material is
    `neumat.reflectance.btf.read_ubo2014`.

    texels: (row0, col0, height, width) crop in our texel convention (row 0 at the top); default: all.
    step: keep every step-th row and column of the crop (plain decimation, no prefilter).
    max_components: use at most this many SVD components per channel (truncation; default: all stored).
    max_gib: refuse (InputError) to build a table larger than this many GiB of float32; a full 400 x 400
    UBO2014 table is about 43 GiB, so crop or decimate.
    """
    header = read_ubo2014_header(path)
    rows, cols = _texel_grid(header, texels, step)
    if max_components is not None and (not isinstance(max_components, int) or max_components < 1):
        raise InputError(f"read_ubo2014 max_components: expected a positive integer, got {max_components!r}")
    n_l, n_v = len(header.light_angles), len(header.view_angles)
    gib = n_l * n_v * len(rows) * len(cols) * 3 * 4 / 2 ** 30
    if gib > max_gib:
        raise InputError(f"read_ubo2014 {header.path}: a {len(rows)} x {len(cols)}-texel table of {n_l} x {n_v} "
                         f"directions needs {gib:.1f} GiB (max_gib={max_gib}); pass texels=(row0, col0, h, w), "
                         "step or a larger max_gib")
    stored_rows = header.height - 1 - rows
    xy = (stored_rows[:, None] * header.width + cols[None, :]).reshape(-1)
    lv = np.arange(n_l * n_v)
    factors = []
    for ch in header.channels:
        k = ch.components if max_components is None else min(ch.components, max_components)
        factors.append((ch.angular.load(header.path, lv, k).reshape(n_v, n_l, k),
                        ch.spatial.load(header.path, xy, k)))
    light_dirs = header.light_dirs()
    data = torch.empty(n_l, n_v, len(rows), len(cols), 3)
    for v in range(n_v):
        decorrelated = torch.stack([a[v] @ s.T for a, s in factors], -1)      # (L, texels, 3)
        rgb = decode_colors(decorrelated, header)
        if header.cosine_flag:
            rgb = rgb / light_dirs[:, 2, None, None]
        data[:, v] = rgb.reshape(n_l, len(rows), len(cols), 3)
    return BTFTable(data.to(device), light_dirs.to(device), header.view_dirs().to(device), label=header.path.stem)


def decode_colors(values: torch.Tensor, header: Ubo2014Header) -> torch.Tensor:
    """Linear RGB (..., 3) from decorrelated channels (..., 3): colour model, then dynamic-range reduction."""
    model = header.color_model
    x = values.double()
    yuv = torch.tensor(YUV_TO_RGB, dtype=x.dtype)
    if model == 1:
        x = x @ yuv.T
    elif model == 3:
        x = x @ torch.as_tensor(header.color_matrix, dtype=x.dtype) + torch.as_tensor(header.color_mean, dtype=x.dtype)
    elif model == 4:
        x = x @ torch.tensor(YCOCG_TO_RGB, dtype=x.dtype).T
    elif model in (9, 10, 11):
        y = x[..., :1].exp() - DRR_EPS
        uv = x[..., 1:]
        if model == 10:
            uv = uv.sign() * (uv.abs() + math.log(DRR_EPS)).exp()
        elif model == 11:
            uv = uv * (y + DRR_EPS)
        x = torch.cat([y, uv], -1) @ yuv.T
    elif model == 12:
        x = x.exp() - DRR_EPS
    if header.dynamic_range_reduction:
        x = x.exp() - DRR_EPS
    return x.to(values.dtype)


def _texel_grid(header: Ubo2014Header, texels, step) -> tuple[np.ndarray, np.ndarray]:
    """Our row indices and column indices of the requested crop."""
    if not isinstance(step, int) or step < 1:
        raise InputError(f"read_ubo2014 step: expected a positive integer, got {step!r}")
    if texels is None:
        texels = (0, 0, header.height, header.width)
    if len(texels) != 4 or not all(isinstance(t, (int, np.integer)) for t in texels):
        raise InputError(f"read_ubo2014 texels: expected (row0, col0, height, width) integers, got {texels!r}")
    r0, c0, h, w = (int(t) for t in texels)
    if r0 < 0 or c0 < 0 or h < 1 or w < 1 or r0 + h > header.height or c0 + w > header.width:
        raise InputError(f"read_ubo2014 texels={texels}: the crop must lie inside the "
                         f"{header.height} x {header.width} texture")
    return np.arange(r0, r0 + h, step), np.arange(c0, c0 + w, step)


class _HeaderParser:
    """Sequential little-endian reads that raise DataFormatError naming the file on any inconsistency."""

    def __init__(self, path: Path, f, size: int) -> None:
        self.path, self.f, self.size = path, f, size

    def fail(self, problem: str):
        raise DataFormatError(f"{self.path}: {problem}")

    def read(self, n: int, what: str) -> bytes:
        data = self.f.read(n)
        if len(data) != n:
            self.fail(f"truncated file: ended while reading {what} at byte {self.f.tell()}")
        return data

    def unpack(self, fmt: str, what: str):
        values = struct.unpack("<" + fmt, self.read(struct.calcsize("<" + fmt), what))
        return values[0] if len(values) == 1 else values

    def text(self, n: int, what: str) -> str:
        if n > self.size - self.f.tell():
            self.fail(f"truncated file: {what} claims {n} bytes, only {self.size - self.f.tell()} left")
        return self.read(n, what).split(b"\0", 1)[0].decode("latin-1")

    def parse(self) -> Ubo2014Header:
        start = self.f.read(16)
        matches = [s for s in list(SIGNATURES) + list(UNSUPPORTED_SIGNATURES) if start.startswith(s)]
        if not matches:
            self.fail(f"unknown signature {start[:10]!r}; expected one of the Bonn BTF signatures "
                      f"{', '.join(s.decode() for s in SIGNATURES)}")
        signature = max(matches, key=len)
        if signature in UNSUPPORTED_SIGNATURES:
            self.fail(f"unsupported Bonn BTF variant {signature.decode()} ({UNSUPPORTED_SIGNATURES[signature]}); "
                      "this reader handles DFMF and FMF files")
        variant, extended = SIGNATURES[signature]
        self.f.seek(len(signature))
        meta = self.meta_data()
        light_angles, view_angles = self.directions()
        width, height = self.unpack("II", "texture size")
        if width < 1 or height < 1:
            self.fail(f"texture size {width} x {height} is empty")
        if signature.endswith(b"R"):
            n_rot = self.unpack("I", "rotation count")
            self.skip(36 * n_rot, f"{n_rot} rotation matrices")
        n_lv, n_xy = len(light_angles) * len(view_angles), width * height
        color = {"color_model": 0, "color_mean": np.zeros(3), "color_matrix": np.eye(3),
                 "dynamic_range_reduction": False}
        if variant == "DFMF":
            max_components, dfmf_color = self.dfmf_color()
            color.update(dfmf_color)
            channels, scalar_size = self.dfmf_channels(meta["n_channels"], n_lv, n_xy, max_components)
        else:
            color["dynamic_range_reduction"] = self.fmf_extended_header() if extended else False
            channels, scalar_size = self.fmf_channels(meta["n_channels"], n_lv, n_xy)
        end = self.f.tell()
        if end != self.size:
            self.fail(f"{self.size - end} unexpected trailing bytes after the factor matrices (layout mismatch?)")
        return Ubo2014Header(self.path, signature.decode(), variant, width, height, light_angles, view_angles,
                             meta["channel_names"], meta["cosine_flag"], scalar_size=scalar_size,
                             measurement_setup=meta["setup"], ppmm=meta["ppmm"], xml=meta["xml"],
                             channels=channels, **color)

    def skip(self, n: int, what: str) -> None:
        if n > self.size - self.f.tell():
            self.fail(f"truncated file: {what} needs {n} bytes, only {self.size - self.f.tell()} left")
        self.f.seek(n, 1)

    def meta_data(self) -> dict:
        begin = self.f.tell()
        block_size, version = self.unpack("II", "meta data size and version")
        setup = self.text(80, "measurement setup")
        self.text(160, "sensor and light source names")
        ppmm = self.unpack("f", "pixels per mm")
        self.unpack("3f", "RGB scale")
        cosine_flag = bool(self.unpack("I", "cosine flag")) if version > 1 else False
        xml = self.text(self.unpack("I", "XML length"), "XML") if version > 2 else ""
        names = ("R", "G", "B")
        if version > 3:
            n = self.unpack("I", "channel count")
            if n > self.size - self.f.tell():
                self.fail(f"implausible channel count {n}")
            names = tuple(self.text(self.unpack("I", "channel name length"), "channel name") for _ in range(n))
        if self.f.tell() - begin != block_size:
            self.fail(f"meta data block says {block_size} bytes but its fields (version {version}) take "
                      f"{self.f.tell() - begin}")
        if len(names) != 3:
            self.fail(f"{len(names)} colour channels {names}; only 3-channel (RGB) BTFs are supported")
        return {"setup": setup, "ppmm": float(ppmm), "cosine_flag": cosine_flag, "xml": xml,
                "channel_names": names, "n_channels": len(names)}

    def directions(self) -> tuple[np.ndarray, np.ndarray]:
        n_view = self.unpack("I", "view count")
        if n_view < 1 or 12 * n_view > self.size - self.f.tell():
            self.fail(f"implausible view count {n_view}")
        views, lights = [], None
        for v in range(n_view):
            views.append(self.unpack("2f", f"angles of view {v}"))
            n_light = self.unpack("I", f"light count of view {v}")
            if lights is None:
                if n_light < 1 or 8 * n_light > self.size - self.f.tell():
                    self.fail(f"implausible light count {n_light}")
                lights = np.frombuffer(self.read(8 * n_light, "light angles"), "<f4").reshape(n_light, 2)
            elif n_light != len(lights):
                self.fail(f"view {v} has {n_light} light directions, view 0 has {len(lights)}; "
                          "view-dependent light sets are not supported")
            else:
                self.skip(8 * n_light, f"light angles of view {v}")
        return lights.astype(np.float64), np.asarray(views, dtype=np.float64)

    def dfmf_color(self) -> tuple[int, dict]:
        max_components = self.unpack("I", "component count")
        model = self.unpack("i", "colour model")
        mean = np.asarray(self.unpack("3f", "colour mean"), dtype=np.float64)
        matrix = np.asarray(self.unpack("9f", "colour matrix"), dtype=np.float64).reshape(3, 3)
        if model not in COLOR_MODELS:
            self.fail(f"unsupported colour model {model} (supported: "
                      f"{', '.join(f'{k} {v}' for k, v in COLOR_MODELS.items())})")
        return max_components, {"color_model": model, "color_mean": mean, "color_matrix": matrix}

    def scalar_type(self, scalar_size: int) -> np.dtype:
        if scalar_size not in _SCALAR_TYPES:
            self.fail(f"scalar size {scalar_size} bytes; expected 2 (float16), 4 (float32) or 8 (float64)")
        return _SCALAR_TYPES[scalar_size]

    def matrices(self, dtype: np.dtype, p: int, n_rows: int, n_cols: int, what: str) -> tuple[int, int]:
        """Skip the singular values, U and SxV; return the byte offsets of U and SxV."""
        if p < 1:
            self.fail(f"{what}: {p} components")
        self.skip(p * dtype.itemsize, f"{what} singular values")
        u_start = self.f.tell()
        self.skip(n_rows * p * dtype.itemsize, f"{what} U ({n_rows} x {p})")
        sxv_start = self.f.tell()
        self.skip(n_cols * p * dtype.itemsize, f"{what} SxV ({n_cols} x {p})")
        return u_start, sxv_start

    def dfmf_channels(self, n_channels: int, n_lv: int, n_xy: int, max_components: int):
        channels, sizes = [], set()
        for c in range(n_channels):
            scalar_size, p, n_rows, n_cols = self.unpack("BIII", f"channel {c} matrix header")
            dtype = self.scalar_type(scalar_size)
            sizes.add(scalar_size)
            if p > max_components:
                self.fail(f"channel {c} stores {p} components, more than the {max_components} of the header")
            if (n_rows, n_cols) not in ((n_lv, n_xy), (n_xy, n_lv)):
                self.fail(f"channel {c}: U is {n_rows} x {p} and SxV {n_cols} x {p}, but the header gives "
                          f"{n_lv} direction pairs and {n_xy} texels")
            u_start, sxv_start = self.matrices(dtype, p, n_rows, n_cols, f"channel {c}")
            u = FactorRows(u_start, n_rows, p, dtype)
            sxv = FactorRows(sxv_start, n_cols, p, dtype)
            channels.append(ChannelFactors(u, sxv, p) if n_rows == n_lv else ChannelFactors(sxv, u, p))
        return tuple(channels), max(sizes)

    def fmf_extended_header(self) -> bool:
        version = self.unpack("B", "extended header version")
        if version >= 3:
            self.fail(f"unknown FMF extended header version {version}")
        drr = bool(self.unpack("I", "dynamic-range reduction flag")) if version >= 1 else False
        if version >= 2:
            hw, hh = self.unpack("II", "height map size")
            self.skip(2 * hw * hh, f"{hw} x {hh} height map")
        return drr

    def fmf_channels(self, n_channels: int, n_lv: int, n_xy: int):
        p_first, scalar_size, p, n_rows, n_cols = self.unpack("IBIII", "FMF matrix header")
        if p_first != p:
            self.fail(f"FMF component counts disagree ({p_first} and {p})")
        dtype = self.scalar_type(scalar_size)
        if (n_rows, n_cols) not in ((n_channels * n_lv, n_xy), (n_channels * n_xy, n_lv)):
            self.fail(f"U is {n_rows} x {p} and SxV {n_cols} x {p}, but the header gives {n_channels} channels, "
                      f"{n_lv} direction pairs and {n_xy} texels")
        u_start, sxv_start = self.matrices(dtype, p, n_rows, n_cols, "FMF")
        channels = []
        for c in range(n_channels):
            u = FactorRows(u_start, n_rows, p, dtype, offset=c, stride=n_channels)
            sxv = FactorRows(sxv_start, n_cols, p, dtype)
            channels.append(ChannelFactors(u, sxv, p) if n_rows == n_channels * n_lv else ChannelFactors(sxv, u, p))
        return tuple(channels), scalar_size


__all__ = ["COLOR_MODELS", "SIGNATURES", "Ubo2014Header", "angles_to_directions", "decode_colors", "read_ubo2014_table",
           "read_ubo2014_header"]
