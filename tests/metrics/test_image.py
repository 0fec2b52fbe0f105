"""Tone mapping and image metrics: the sRGB formula, known values, and input checks before FLIP runs."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from neumat.core.errors import InputError, UnknownNameError
from neumat.metrics import image as image_module
from neumat.metrics.image import flip_map, hdr_flip, image_metrics, masked_flip
from neumat.color.tonemap import srgb_decode, srgb_encode, to_ldr


def srgb_reference(x: float) -> float:
    """IEC 61966-2-1, written out in float64."""
    return 12.92 * x if x <= 0.0031308 else 1.055 * x ** (1 / 2.4) - 0.055


def test_srgb_pair_matches_the_standard_formula():
    x = np.concatenate([np.linspace(0, 1, 1001), [0.0031308, 0.00313, 0.0031316]])
    want = np.array([srgb_reference(v) for v in x])
    np.testing.assert_allclose(srgb_encode(x), want, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(srgb_decode(want), x, rtol=1e-9, atol=1e-12)
    assert srgb_encode(np.float64(0.5)) == pytest.approx(0.7353569830524495, abs=1e-15)
    t = torch.tensor(x, dtype=torch.float32)
    np.testing.assert_allclose(srgb_encode(t).numpy(), want, atol=2e-7)
    assert srgb_encode(t).dtype == torch.float32 and srgb_encode(x.astype(np.float32)).dtype == np.float32


def test_to_ldr_tone_curves_and_exposure():
    x = np.array([0.0, 0.25, 1.0, 4.0, -1.0])
    np.testing.assert_allclose(to_ldr(x), [srgb_reference(min(max(v, 0), 1)) for v in x], rtol=1e-12)
    np.testing.assert_allclose(to_ldr(x, exposure=2), to_ldr(4 * x), rtol=1e-12)
    np.testing.assert_allclose(to_ldr(x, tonemap="reinhard"),
                               [srgb_reference(max(v, 0) / (1 + max(v, 0))) for v in x], rtol=1e-12)
    aces_1 = (2.51 + 0.03) / (2.43 + 0.59 + 0.14)            # Narkowicz curve at x = 1
    assert to_ldr(np.array([1.0]), tonemap="aces")[0] == pytest.approx(srgb_reference(aces_1), rel=1e-12)
    assert to_ldr(np.array([1e6]), tonemap="aces")[0] == pytest.approx(1.0)
    for curve in ("clip", "reinhard", "aces"):
        t = to_ldr(torch.tensor(x, dtype=torch.float64), exposure=0.5, tonemap=curve)
        np.testing.assert_allclose(t.numpy(), to_ldr(x, exposure=0.5, tonemap=curve), rtol=1e-12)
    with pytest.raises(UnknownNameError, match="did you mean reinhard"):
        to_ldr(x, tonemap="reinhart")


def smooth_image(h=32, w=40) -> np.ndarray:
    """A smooth linear image whose sRGB values lie in [0.2, 0.6]."""
    yy, xx = np.meshgrid(np.linspace(0, 1, h), np.linspace(0, 1, w), indexing="ij")
    srgb = np.stack([0.2 + 0.4 * xx, 0.2 + 0.4 * yy, 0.4 + 0.2 * xx * yy], -1)
    return srgb_decode(srgb).astype(np.float32)


def test_identical_images_have_zero_error():
    img = smooth_image()
    m = image_metrics(img, torch.from_numpy(img.copy()))
    assert set(m) == {"flip", "ssim", "psnr", "rmse", "mae", "hdr_flip"}
    assert m["flip"] == 0 and m["hdr_flip"] == 0 and m["rmse"] == 0 and m["mae"] == 0
    assert m["ssim"] == pytest.approx(1.0, abs=1e-12) and m["psnr"] == math.inf


def test_constant_display_shift_gives_known_rmse_mae_psnr():
    ref = smooth_image()
    test = srgb_decode(srgb_encode(ref.astype(np.float64)) + 0.1).astype(np.float32)   # +0.1 in sRGB
    m = image_metrics(ref, test)
    assert m["rmse"] == pytest.approx(0.1, abs=2e-6)
    assert m["mae"] == pytest.approx(0.1, abs=2e-6)
    assert m["psnr"] == pytest.approx(20.0, abs=2e-4)                # 10 log10(1 / 0.1^2)
    assert 0 < m["flip"] < 1 and 0 < m["hdr_flip"] < 1 and 0 < m["ssim"] < 1


def test_exposure_and_tonemap_are_applied_before_ldr_metrics():
    ref = smooth_image()
    bright = image_metrics(ref * 64, ref * 64)          # identical, whatever the tone map
    assert bright["rmse"] == 0
    # at exposure -6 the x64 image displays like the original, so the shift test repeats exactly
    test = srgb_decode(srgb_encode(ref.astype(np.float64)) + 0.1).astype(np.float32)
    m = image_metrics(ref * 64, test * 64, exposure=-6)
    assert m["rmse"] == pytest.approx(0.1, abs=2e-6)
    assert image_metrics(ref, test, tonemap="reinhard")["rmse"] < 0.1


def test_flip_map_shape_and_mean():
    ref = smooth_image()
    test = ref * 1.3
    fm = flip_map(ref, test)
    assert fm.shape == ref.shape[:2] and fm.dtype == np.float32
    assert 0 <= fm.min() and fm.max() <= 1
    assert float(fm.mean(dtype=np.float64)) == pytest.approx(image_metrics(ref, test)["flip"], rel=1e-6)


def test_masked_flip_averages_the_flip_map_over_the_mask():
    ref = smooth_image()
    test = ref.copy()
    test[:, 20:] *= 1.5  # only the right half differs
    left, right = np.zeros(ref.shape[:2], bool), np.zeros(ref.shape[:2], bool)
    left[:, :20], right[:, 20:] = True, True
    fm = flip_map(ref, test)
    assert masked_flip(ref, test, right) == pytest.approx(float(fm[:, 20:].mean(dtype=np.float64)), rel=1e-6)
    # FLIP filters spatially, so some error spreads into the left half, but most of it is on the right
    assert masked_flip(ref, test, right) > image_metrics(ref, test)["flip"] > masked_flip(ref, test, left)
    assert math.isnan(masked_flip(ref, test, np.zeros(ref.shape[:2], bool)))
    with pytest.raises(InputError, match="mask"):
        masked_flip(ref, test, left[:4])


def test_hdr_flip_on_black_references_does_not_abort():
    img = smooth_image()
    black = np.zeros_like(img)
    assert hdr_flip(black, black) == 0.0
    assert 0 < hdr_flip(black, img) <= 1
    assert hdr_flip(img - 0.5, img - 0.5) == 0                       # negatives are clamped, not passed on


@pytest.fixture
def flip_must_not_run(monkeypatch):
    import flip_evaluator

    def fail(*args, **kwargs):
        raise AssertionError("flip_evaluator.evaluate was called with bad input")
    monkeypatch.setattr(flip_evaluator, "evaluate", fail)


@pytest.mark.parametrize("ref_shape, test_shape, match", [
    ((16, 16, 3), (16, 17, 3), "differ in shape"),
    ((16, 16), (16, 16), r"\(H, W, 3\)"),
    ((16, 16, 4), (16, 16, 4), r"\(H, W, 3\)"),
    ((5, 16, 3), (5, 16, 3), "at least 7 x 7"),
])
def test_bad_shapes_raise_before_flip(flip_must_not_run, ref_shape, test_shape, match):
    with pytest.raises(InputError, match=match):
        image_metrics(np.ones(ref_shape, np.float32), np.ones(test_shape, np.float32))


@pytest.mark.parametrize("fn", [image_metrics, flip_map, hdr_flip])
@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_non_finite_pixels_raise_before_flip(flip_must_not_run, fn, bad):
    ref = smooth_image(8, 8)
    test = ref.copy()
    test[3, 4, 1] = bad
    with pytest.raises(InputError, match="non-finite"):
        fn(ref, test)


def test_flip_input_checks(flip_must_not_run):
    ok = np.full((8, 8, 3), 0.5, np.float32)
    with pytest.raises(InputError, match=r"\[0, 1\]"):
        image_module._flip(ok, ok * 3, "LDR")
    with pytest.raises(InputError, match=r"\[0, inf\)"):
        image_module._flip(ok, -ok, "HDR")
