"""Image files: round trips per format, the Radiance codec against the spec and Mitsuba, clear errors."""
from __future__ import annotations


import numpy as np
import pytest
import torch

from mitsuba_util import mitsuba_or_skip
from neumat.core.errors import DataFormatError, InputError
from neumat.io.images import image_to_numpy, read_image, write_image, write_image_ldr
from neumat.color.tonemap import srgb_encode


def hdr_image(h=9, w=13, seed=0) -> np.ndarray:
    """Linear values spanning ~8 decades, with some exact zeros."""
    rng = np.random.default_rng(seed)
    img = (10.0 ** rng.uniform(-4, 4, size=(h, w, 3))).astype(np.float32)
    img[0, 0] = 0
    return img


def test_exr_round_trip_is_exact(tmp_path):
    img = hdr_image()
    img[1, 1] = [-0.5, 1e-30, 3e38]          # EXR float32 keeps negatives, denormal-range and huge values
    write_image(tmp_path / "a.exr", torch.from_numpy(img))
    back = read_image(tmp_path / "a.exr")
    assert back.dtype == np.float32 and back.shape == img.shape
    assert np.array_equal(back, img)


def test_exr_half_and_luminance_channels(tmp_path):
    import OpenEXR

    img = (hdr_image() / 1e4).astype(np.float16).astype(np.float32)   # exactly representable in half
    header = {"compression": OpenEXR.PIZ_COMPRESSION, "type": OpenEXR.scanlineimage}
    with OpenEXR.File(header, {"RGBA": np.concatenate([img, np.ones_like(img[..., :1])], -1).astype(np.float16)}) as f:
        f.write(str(tmp_path / "half.exr"))
    assert np.array_equal(read_image(tmp_path / "half.exr"), img)
    with OpenEXR.File(header, {"Y": img[..., 1].copy()}) as f:
        f.write(str(tmp_path / "grey.exr"))
    assert np.array_equal(read_image(tmp_path / "grey.exr"), np.repeat(img[..., 1:2], 3, axis=2))
    with OpenEXR.File(header, {"Z": img[..., 1].copy()}) as f:
        f.write(str(tmp_path / "depth.exr"))
    with pytest.raises(DataFormatError, match="channels R, G, B"):
        read_image(tmp_path / "depth.exr")


@pytest.mark.parametrize("width", [13, 5])     # run-length encoded scanlines (8 <= W), flat ones (W < 8)
def test_hdr_round_trip_within_rgbe_precision(tmp_path, width):
    img = hdr_image(w=width)
    img[2, :] = 7.25                            # long runs
    write_image(tmp_path / "a.hdr", img)
    assert (tmp_path / "a.hdr").read_bytes().startswith(b"#?RADIANCE\n")
    back = read_image(tmp_path / "a.hdr")
    assert back.dtype == np.float32 and back.shape == img.shape
    # RGBE keeps an 8-bit mantissa relative to the largest channel: |error| <= 2^-8 max(r, g, b)
    peak = img.max(axis=-1, keepdims=True)
    assert np.all(np.abs(back - img) <= 2.0 ** -8 * peak * (1 + 1e-6))
    assert np.all(back[0, 0] == 0)


def test_hdr_negative_values_are_written_as_zero(tmp_path):
    img = np.full((2, 10, 3), 0.5, np.float32)
    img[0, 0, 1] = -3
    write_image(tmp_path / "n.hdr", img)
    assert 0 <= read_image(tmp_path / "n.hdr")[0, 0, 1] <= 2.0 ** -8 * 0.5


def rgbe_file(width: int, scanline: bytes, header: bytes = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n") -> bytes:
    return header + f"-Y 1 +X {width}\n".encode() + scanline


def test_hdr_decodes_a_hand_written_run_length_scanline(tmp_path):
    # Radiance new-style RLE: 2 2 W_hi W_lo, then per component runs (128 + n, value) or literals (n, bytes)
    width = 8
    line = bytes([2, 2, 0, width])
    line += bytes([128 + 8, 128])                       # R: 8 x 128
    line += bytes([8, 0, 16, 32, 64, 96, 128, 192, 255])  # G: literal
    line += bytes([128 + 3, 0, 5, 1, 2, 3, 4, 5])          # B: run of 3 zeros, literal of 5
    line += bytes([128 + 8, 129])                       # E: exponent 129 -> scale 2^(129 - 136)
    (tmp_path / "rle.hdr").write_bytes(rgbe_file(width, line))
    got = read_image(tmp_path / "rle.hdr")[0]
    mant = np.array([[128] * 8, [0, 16, 32, 64, 96, 128, 192, 255], [0, 0, 0, 1, 2, 3, 4, 5]], np.float64).T
    np.testing.assert_allclose(got, (mant + 0.5) * 2.0 ** -7, rtol=1e-7)


def test_hdr_flat_scanline_and_exposure_header(tmp_path):
    pixels = bytes([128, 64, 0, 130, 0, 0, 0, 0])          # (128, 64, 0) x 2^(130-136), then black
    header = b"#?RGBE\nFORMAT=32-bit_rle_rgbe\nEXPOSURE=2\n\n"
    (tmp_path / "flat.hdr").write_bytes(rgbe_file(2, pixels, header))
    got = read_image(tmp_path / "flat.hdr")[0]
    np.testing.assert_allclose(got[0], np.array([128.5, 64.5, 0.5]) * 2.0 ** -6 / 2, rtol=1e-7)
    assert np.all(got[1] == 0)


@pytest.mark.parametrize("content, match", [
    (b"P6 not radiance", "signature"),
    (b"#?RADIANCE\nFORMAT=32-bit_rle_xyze\n\n-Y 1 +X 2\n" + bytes(8), "FORMAT"),
    (b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n+X 2 -Y 1\n" + bytes(8), "resolution line"),
    (b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n-Y 1 +X 2\n" + bytes(8), "empty line"),
    (b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 2 +X 2\n" + bytes(12), "truncated"),
    (b"#?RADIANCE\n\n-Y 1 +X 8\n" + bytes([2, 2, 0, 9]) + bytes(40), "width"),
    (b"#?RADIANCE\n\n-Y 1 +X 8\n" + bytes([2, 2, 0, 8, 128 + 40, 1]), "run length"),
    (b"#?RADIANCE\n\n-Y 1 +X 8\n" + bytes([2, 2, 0, 8, 128 + 8, 1, 8, 1, 2]), "truncated"),
])
def test_hdr_malformed_files_raise(tmp_path, content, match):
    (tmp_path / "bad.hdr").write_bytes(content)
    with pytest.raises(DataFormatError, match=match):
        read_image(tmp_path / "bad.hdr")


def test_png_round_trip_within_8_bit_quantisation(tmp_path):
    rng = np.random.default_rng(1)
    img = rng.uniform(0, 1.2, size=(6, 7, 3)).astype(np.float32)   # > 1 is clipped by the "clip" tone map
    write_image(tmp_path / "a.png", img)
    back = read_image(tmp_path / "a.png")
    assert back.dtype == np.float32 and back.shape == img.shape
    # compare in the encoded domain, where the quantisation step is 1/255
    assert np.abs(srgb_encode(back) - srgb_encode(np.clip(img, 0, 1))).max() <= 0.5 / 255 + 1e-6
    raw = read_image(tmp_path / "a.png", srgb=False)
    assert np.allclose(raw * 255, np.round(raw * 255), atol=1e-4)


def test_png_exposure_and_jpg(tmp_path):
    img = np.full((4, 4, 3), 0.25, np.float32)
    write_image(tmp_path / "e.png", img, exposure=2.0)          # 0.25 * 2^2 = 1 -> white
    assert np.all(read_image(tmp_path / "e.png", srgb=False) == 1.0)
    write_image(tmp_path / "a.jpg", img)
    back = read_image(tmp_path / "a.jpg")
    assert back.shape == (4, 4, 3) and np.abs(back - 0.25).max() < 0.02


def test_sixteen_bit_grey_png(tmp_path):
    from PIL import Image

    grey = np.array([[0, 65535], [32768, 1000]], np.uint16)
    Image.fromarray(grey).save(tmp_path / "g16.png")
    back = read_image(tmp_path / "g16.png", srgb=False)
    assert back.shape == (2, 2, 3)
    np.testing.assert_allclose(back[..., 1], grey / 65535.0, rtol=1e-6)


def test_write_image_ldr_uint8_and_float(tmp_path):
    rng = np.random.default_rng(2)
    img = rng.integers(0, 256, size=(5, 6, 3), dtype=np.uint8)
    write_image_ldr(tmp_path / "u.png", img)
    assert np.array_equal(np.round(read_image(tmp_path / "u.png", srgb=False) * 255).astype(np.uint8), img)
    write_image_ldr(tmp_path / "sub/f.png", torch.full((2, 3, 3), 0.5))
    assert np.all(read_image(tmp_path / "sub/f.png", srgb=False) == 128 / 255)
    with pytest.raises(InputError, match=r"\[0, 1\]"):
        write_image_ldr(tmp_path / "f.png", np.full((2, 2, 3), 1.5, np.float32))
    with pytest.raises(InputError, match="must end in"):
        write_image_ldr(tmp_path / "f.exr", img)


@pytest.mark.parametrize("suffix", [".exr", ".hdr", ".png"])
@pytest.mark.parametrize("shape", [(4, 4), (4, 4, 4), (0, 4, 3), (4, 4, 3, 1)])
def test_write_rejects_wrong_shapes(tmp_path, suffix, shape):
    with pytest.raises(InputError, match=r"\(H, W, 3\)"):
        write_image(tmp_path / f"x{suffix}", np.ones(shape, np.float32))


@pytest.mark.parametrize("suffix", [".exr", ".hdr", ".png"])
@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_write_rejects_non_finite_pixels(tmp_path, suffix, bad):
    img = np.ones((3, 3, 3), np.float32)
    img[1, 2, 0] = bad
    with pytest.raises(InputError, match="non-finite"):
        write_image(tmp_path / f"x{suffix}", img)
    assert not (tmp_path / f"x{suffix}").exists()


def test_bad_types_paths_and_suffixes(tmp_path):
    with pytest.raises(InputError, match="numpy array or torch tensor"):
        write_image(tmp_path / "x.exr", [[[1.0, 1.0, 1.0]]])
    with pytest.raises(InputError, match="dtype"):
        image_to_numpy(np.ones((2, 2, 3), dtype=complex))
    with pytest.raises(InputError, match="does not exist"):
        read_image(tmp_path / "missing.exr")
    with pytest.raises(InputError, match="unsupported image suffix '.bmp'"):
        read_image(tmp_path / "x.bmp")
    with pytest.raises(InputError, match="unsupported image suffix '.tiff'"):
        write_image(tmp_path / "x.tiff", np.ones((2, 2, 3), np.float32))


def test_truncated_and_corrupt_files_raise(tmp_path):
    img = hdr_image(32, 32)
    for suffix in (".exr", ".hdr", ".png"):
        write_image(tmp_path / f"a{suffix}", img)
        data = (tmp_path / f"a{suffix}").read_bytes()
        (tmp_path / f"t{suffix}").write_bytes(data[: len(data) // 2])
        with pytest.raises(DataFormatError):
            read_image(tmp_path / f"t{suffix}")
        (tmp_path / f"g{suffix}").write_bytes(b"definitely not an image")
        with pytest.raises(DataFormatError):
            read_image(tmp_path / f"g{suffix}")


@pytest.mark.mitsuba
def test_radiance_and_exr_files_agree_with_mitsuba(tmp_path):
    mi = mitsuba_or_skip()
    img = hdr_image(12, 20)
    write_image(tmp_path / "ours.hdr", img)
    write_image(tmp_path / "ours.exr", img)
    theirs = np.array(mi.Bitmap(str(tmp_path / "ours.hdr")), dtype=np.float32)
    peak = img.max(axis=-1, keepdims=True)
    # Mitsuba decodes m 2^(e-136), Radiance (and we) (m + 0.5) 2^(e-136): at most 2^-8 of the peak apart
    assert np.all(np.abs(theirs - read_image(tmp_path / "ours.hdr")) <= 2.0 ** -8 * peak * (1 + 1e-6))
    assert np.array_equal(np.array(mi.Bitmap(str(tmp_path / "ours.exr")), dtype=np.float32), img)
    mi.Bitmap(img).write(str(tmp_path / "theirs.hdr"))                 # Mitsuba writes RLE scanlines
    assert np.all(np.abs(read_image(tmp_path / "theirs.hdr") - img) <= 2.0 ** -7 * peak)


def test_shared_environment_maps(shared_data):
    for name in ("forest_slope_1k.hdr", "studio_small_03_1k.hdr", "venice_sunset_1k.hdr"):
        img = read_image(shared_data / "envmap" / name)
        assert img.shape == (512, 1024, 3) and np.isfinite(img).all() and img.min() >= 0 and img.max() > 10
    museum = read_image(shared_data / "envmap" / "mitsuba_museum.exr")
    assert museum.shape == (256, 512, 3) and np.isfinite(museum).all()
