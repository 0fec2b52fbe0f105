"""Image files: read and write linear float RGB images (H, W, 3).

Formats, chosen by suffix:
  .exr         OpenEXR (the `OpenEXR` package), float32 R, G, B channels, ZIP compression.
  .hdr         Radiance RGBE (own codec: imageio writes TIFF data for .hdr without an extra plugin).
               Reads flat and new-style run-length-encoded scanlines, orientation "-Y H +X W" only;
               writes run-length-encoded scanlines (flat when W < 8 or W > 32767).
  .png .jpg    8-bit sRGB; decoded to linear on read (unless srgb=False); written tone-mapped.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from ..core.errors import DataFormatError, InputError
from ..color.tonemap import srgb_decode, to_ldr

LDR_SUFFIXES = (".png", ".jpg", ".jpeg")
HDR_SUFFIXES = (".exr", ".hdr")
SUFFIXES = LDR_SUFFIXES + HDR_SUFFIXES


def read_image(path: str | Path, srgb: bool = True) -> np.ndarray:
    """Read an image as float32 (H, W, 3). EXR and HDR are linear as stored; 8-bit/16-bit PNG and JPG
    are scaled to [0, 1] and decoded from sRGB to linear unless `srgb` is False. Alpha is dropped,
    grey images are repeated into three channels."""
    path = Path(path)
    suffix = _suffix(path, "read_image")
    if not path.is_file():
        raise InputError(f"image {path}: does not exist")
    if suffix == ".exr":
        return _read_exr(path)
    if suffix == ".hdr":
        return _read_hdr(path)
    img = _read_ldr(path)
    return srgb_decode(img) if srgb else img


def write_image(path: str | Path, img, exposure: float = 0.0, tonemap: str = "clip") -> None:
    """Write a linear RGB image (H, W, 3) (numpy or torch). EXR and HDR store the linear values
    (HDR clamps negatives to 0, RGBE cannot hold them); PNG and JPG store
    `to_ldr(img, exposure, tonemap)` quantised to 8 bits."""
    path = Path(path)
    suffix = _suffix(path, "write_image")
    arr = image_to_numpy(img, "write_image: img")
    path.parent.mkdir(parents=True, exist_ok=True)
    if suffix == ".exr":
        _write_exr(path, arr)
    elif suffix == ".hdr":
        _write_hdr(path, arr)
    else:
        _write_ldr(path, _quantise(to_ldr(arr, exposure=exposure, tonemap=tonemap)))


def write_image_ldr(path: str | Path, img) -> None:
    """Write a display image to .png / .jpg: uint8 (H, W, 3), or float sRGB values in [0, 1]."""
    path = Path(path)
    if _suffix(path, "write_image_ldr") not in LDR_SUFFIXES:
        raise InputError(f"write_image_ldr: {path} must end in one of {', '.join(LDR_SUFFIXES)}")
    if isinstance(img, torch.Tensor):
        img = img.detach().cpu().numpy()
    if isinstance(img, np.ndarray) and img.dtype == np.uint8:
        _check_shape(img, "write_image_ldr: img")
        out = img
    else:
        arr = image_to_numpy(img, "write_image_ldr: img")
        if arr.size and (arr.min() < 0 or arr.max() > 1):
            raise InputError(f"write_image_ldr: float img must hold sRGB values in [0, 1], "
                             f"got [{arr.min():.4g}, {arr.max():.4g}]")
        out = _quantise(arr)
    path.parent.mkdir(parents=True, exist_ok=True)
    _write_ldr(path, out)


def image_to_numpy(img, name: str = "image") -> np.ndarray:
    """numpy array or torch tensor (H, W, 3) of real values -> finite float32 numpy array (H, W, 3).
    InputError naming `name` for another type, shape or dtype, or for NaN / inf pixels."""
    if isinstance(img, torch.Tensor):
        img = img.detach().cpu()
        img = (img.float() if img.is_floating_point() else img).numpy()
    if not isinstance(img, np.ndarray):
        raise InputError(f"{name}: expected a numpy array or torch tensor, got {type(img).__name__}")
    _check_shape(img, name)
    if not (np.issubdtype(img.dtype, np.floating) or np.issubdtype(img.dtype, np.integer)):
        raise InputError(f"{name}: expected real pixel values, got dtype {img.dtype}")
    arr = np.ascontiguousarray(img, dtype=np.float32)
    bad = int((~np.isfinite(arr)).sum())
    if bad:
        raise InputError(f"{name}: {bad} non-finite value(s) (NaN or inf)")
    return arr


# ---------------------------------------------------------------- checks


def _suffix(path: Path, who: str) -> str:
    suffix = path.suffix.lower()
    if suffix not in SUFFIXES:
        raise InputError(f"{who}: unsupported image suffix {path.suffix!r} in {path} "
                         f"(supported: {', '.join(SUFFIXES)})")
    return suffix


def _check_shape(arr: np.ndarray, name: str) -> None:
    if arr.ndim != 3 or arr.shape[2] != 3 or arr.shape[0] < 1 or arr.shape[1] < 1:
        raise InputError(f"{name}: expected shape (H, W, 3), got {tuple(arr.shape)}")


def _quantise(srgb: np.ndarray) -> np.ndarray:
    """Float sRGB in [0, 1] -> uint8."""
    return np.round(np.clip(srgb, 0.0, 1.0) * 255.0).astype(np.uint8)


# ---------------------------------------------------------------- PNG / JPG


def _read_ldr(path: Path) -> np.ndarray:
    """8- or 16-bit PNG / JPG -> float32 (H, W, 3) in [0, 1], still sRGB-encoded."""
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as im:
            im.load()
            if im.mode in ("I;16", "I;16B", "I;16L", "I"):
                grey = np.asarray(im, dtype=np.float32) / 65535.0
                return np.repeat(grey[:, :, None], 3, axis=2)
            return np.asarray(im.convert("RGB"), dtype=np.float32) / 255.0
    except (UnidentifiedImageError, OSError, SyntaxError, Image.DecompressionBombError) as e:
        raise DataFormatError(f"image {path}: cannot decode ({e})") from e


def _write_ldr(path: Path, img: np.ndarray) -> None:
    from PIL import Image

    options = {"quality": 95} if path.suffix.lower() in (".jpg", ".jpeg") else {}
    Image.fromarray(img, mode="RGB").save(path, **options)


# ---------------------------------------------------------------- EXR


def _read_exr(path: Path) -> np.ndarray:
    import OpenEXR

    try:
        with OpenEXR.File(str(path), separate_channels=True) as f:
            channels = {name: ch.pixels for name, ch in f.channels().items()}
    except (RuntimeError, ValueError) as e:
        raise DataFormatError(f"EXR file {path}: cannot read ({e})") from e
    if all(c in channels for c in "RGB"):
        planes = [channels[c] for c in "RGB"]
    elif "Y" in channels:
        planes = [channels["Y"]] * 3
    else:
        raise DataFormatError(f"EXR file {path}: needs channels R, G, B (or Y), has {sorted(channels)}")
    return np.ascontiguousarray(np.stack(planes, axis=-1), dtype=np.float32)


def _write_exr(path: Path, img: np.ndarray) -> None:
    import OpenEXR

    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with OpenEXR.File(header, {"RGB": img}) as f:
        f.write(str(path))


# ---------------------------------------------------------------- Radiance RGBE


def _read_hdr(path: Path) -> np.ndarray:
    data = path.read_bytes()
    if not data.startswith(b"#?"):
        raise DataFormatError(f"Radiance file {path}: missing the '#?' signature")
    end = data.find(b"\n\n")
    if end < 0:
        raise DataFormatError(f"Radiance file {path}: header does not end with an empty line")
    exposure = 1.0
    for line in data[:end].split(b"\n")[1:]:
        if line.startswith(b"FORMAT=") and line.strip() != b"FORMAT=32-bit_rle_rgbe":
            raise DataFormatError(f"Radiance file {path}: {line.decode(errors='replace')}, "
                                  "expected FORMAT=32-bit_rle_rgbe")
        if line.startswith(b"EXPOSURE="):
            try:
                exposure *= float(line[9:])
            except ValueError:
                raise DataFormatError(f"Radiance file {path}: bad header line {line[:40]!r}") from None
    eol = data.find(b"\n", end + 2)
    parts = data[end + 2:eol].split() if eol > 0 else []
    if len(parts) != 4 or parts[0] != b"-Y" or parts[2] != b"+X" or not (parts[1].isdigit() and parts[3].isdigit()):
        raise DataFormatError(f"Radiance file {path}: resolution line {data[end + 2:eol][:40]!r}, "
                              "expected '-Y <height> +X <width>'")
    height, width = int(parts[1]), int(parts[3])
    raw = np.frombuffer(data, dtype=np.uint8, offset=eol + 1)
    # run-length coding stores at most 127 pixels of a channel in 2 bytes: fewer bytes cannot hold the pixels
    if not (height > 0 and width > 0) or height * width * 4 > 64 * len(raw):
        raise DataFormatError(f"Radiance file {path}: declares {width} x {height} pixels, more than its "
                              f"{len(raw)} bytes of data can hold (truncated or corrupt header?)")
    rgbe = np.empty((height, width, 4), dtype=np.uint8)
    pos = 0
    for y in range(height):
        try:
            rgbe[y], pos = _decode_scanline(raw, pos, width)
        except IndexError:
            raise DataFormatError(f"Radiance file {path}: truncated in scanline {y} of {height}") from None
        except ValueError as e:
            raise DataFormatError(f"Radiance file {path}: scanline {y}: {e}") from None
    return _rgbe_to_float(rgbe) / np.float32(exposure)


def _decode_scanline(raw: np.ndarray, pos: int, width: int) -> tuple[np.ndarray, int]:
    """One scanline -> ((width, 4) uint8 RGBE, new position). IndexError when the data runs out."""
    head = raw[pos:pos + 4]
    is_rle = (8 <= width <= 0x7FFF and len(head) == 4 and head[0] == 2 and head[1] == 2
              and not head[2] & 0x80)
    if not is_rle:
        if pos + 4 * width > len(raw):
            raise IndexError
        return raw[pos:pos + 4 * width].reshape(width, 4), pos + 4 * width
    if (int(head[2]) << 8 | int(head[3])) != width:
        raise ValueError(f"run-length header width {int(head[2]) << 8 | int(head[3])} != image width {width}")
    pos += 4
    out = np.empty(4 * width, dtype=np.uint8)
    i = 0
    while i < 4 * width:
        count = int(raw[pos])
        run = count > 128
        n = count - 128 if run else count
        if n == 0 or i + n > 4 * width:
            raise ValueError(f"bad run length {n} at byte {i} of {4 * width}")
        if run:
            out[i:i + n] = raw[pos + 1]
            pos += 2
        else:
            if pos + 1 + n > len(raw):
                raise IndexError
            out[i:i + n] = raw[pos + 1:pos + 1 + n]
            pos += 1 + n
        i += n
    return out.reshape(4, width).T, pos


def _rgbe_to_float(rgbe: np.ndarray) -> np.ndarray:
    """(..., 4) uint8 RGBE -> (..., 3) float32: (m + 0.5) 2^(e - 136), 0 where e = 0 (Radiance colr_color)."""
    e = rgbe[..., 3:4].astype(np.int32)
    f = np.ldexp(rgbe[..., :3].astype(np.float32) + 0.5, e - 136).astype(np.float32)
    return np.where(e == 0, np.float32(0), f)


def _float_to_rgbe(img: np.ndarray) -> np.ndarray:
    """(..., 3) float32 >= 0 -> (..., 4) uint8 RGBE (Radiance setcolr: mantissa scaled by 256 / max)."""
    v = img.max(axis=-1, keepdims=True)
    mant, e = np.frexp(v)
    zero = v < 1e-32
    scale = np.where(zero, 0.0, mant * 256.0 / np.where(zero, 1.0, v))
    out = np.empty(img.shape[:-1] + (4,), dtype=np.uint8)
    out[..., :3] = np.clip(img * scale, 0, 255).astype(np.uint8)
    out[..., 3:] = np.where(zero, 0, e + 128).astype(np.uint8)
    return out


def _write_hdr(path: Path, img: np.ndarray) -> None:
    img = np.maximum(img, 0.0)
    if img.size and img.max() >= 2.0 ** 127:
        raise InputError(f"write_image: {path}: values up to {img.max():.3g} exceed the RGBE range (< 2^127)")
    rgbe = _float_to_rgbe(img)
    height, width = img.shape[:2]
    chunks = [f"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y {height} +X {width}\n".encode()]
    if 8 <= width <= 0x7FFF:
        for y in range(height):
            chunks.append(bytes([2, 2, width >> 8, width & 0xFF]))
            chunks.extend(_encode_runs(rgbe[y, :, c]) for c in range(4))
    else:
        chunks.append(rgbe.tobytes())
    path.write_bytes(b"".join(chunks))


def _encode_runs(values: np.ndarray) -> bytes:
    """Run-length encode one component of a scanline: runs of >= 4 equal bytes as (128 + n, value),
    the rest as literal blocks (n, n bytes), n <= 127 for runs and <= 128 for literals."""
    change = np.flatnonzero(np.diff(values)) + 1
    starts = np.concatenate([[0], change])
    ends = np.concatenate([change, [len(values)]])
    long = ends - starts >= 4
    out = bytearray()
    pos = 0
    for s, e in zip(starts[long].tolist(), ends[long].tolist()):
        _encode_literal(out, values[pos:s])
        while s < e:
            n = min(127, e - s)
            out += bytes((128 + n, int(values[s])))
            s += n
        pos = e
    _encode_literal(out, values[pos:])
    return bytes(out)


def _encode_literal(out: bytearray, values: np.ndarray) -> None:
    for k in range(0, len(values), 128):
        block = values[k:k + 128]
        out.append(len(block))
        out += block.tobytes()
