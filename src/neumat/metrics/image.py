"""Image metrics between a reference and a test rendering (linear RGB, (H, W, 3), numpy or torch).

LDR metrics (FLIP, SSIM, PSNR, RMSE, MAE) compare the display images `to_ldr(img, exposure, tonemap)`
(sRGB in [0, 1]); HDR-FLIP compares the linear images (negative values clamped to 0).
FLIP is NVIDIA's `flip-evaluator` (Andersson et al. 2020, default 67 pixels per degree).
"""
from __future__ import annotations

import math

import numpy as np

from ..core.errors import InputError
from ..io.images import image_to_numpy
from ..color.tonemap import to_ldr

#: smallest image side SSIM accepts (its 7 x 7 window)
SSIM_MIN_SIDE = 7


def image_metrics(ref, test, tonemap: str = "clip", exposure: float = 0.0) -> dict[str, float]:
    """Metrics of `test` against `ref` (linear RGB (H, W, 3), H, W >= 7).

    Returns {"flip", "ssim", "psnr", "rmse", "mae"} on the tone-mapped sRGB images (data range 1;
    psnr in dB, inf for identical images) and "hdr_flip" on the linear images.
    """
    ref, test = _image_pair(ref, test)
    if min(ref.shape[:2]) < SSIM_MIN_SIDE:
        raise InputError(f"image_metrics: images must be at least {SSIM_MIN_SIDE} x {SSIM_MIN_SIDE} pixels "
                         f"(SSIM window), got {ref.shape[0]} x {ref.shape[1]}")
    ref_ldr = to_ldr(ref, exposure=exposure, tonemap=tonemap)
    test_ldr = to_ldr(test, exposure=exposure, tonemap=tonemap)
    err = test_ldr.astype(np.float64) - ref_ldr.astype(np.float64)
    mse = float(np.mean(err * err))
    return {
        "flip": float(_ldr_flip(ref_ldr, test_ldr).mean(dtype=np.float64)),
        "ssim": _ssim(ref_ldr, test_ldr),
        "psnr": math.inf if mse == 0 else -10.0 * math.log10(mse),
        "rmse": math.sqrt(mse),
        "mae": float(np.mean(np.abs(err))),
        "hdr_flip": hdr_flip(ref, test),
    }


def flip_map(ref, test, tonemap: str = "clip", exposure: float = 0.0) -> np.ndarray:
    """Per-pixel LDR-FLIP error (H, W) float32 in [0, 1] between the tone-mapped images."""
    ref, test = _image_pair(ref, test)
    return _ldr_flip(to_ldr(ref, exposure=exposure, tonemap=tonemap),
                     to_ldr(test, exposure=exposure, tonemap=tonemap))


def masked_flip(ref, test, mask, tonemap: str = "clip", exposure: float = 0.0) -> float:
    """Mean LDR-FLIP (as `image_metrics`) over the pixels where the (H, W) bool `mask` is true (nan if none)."""
    mask = np.asarray(mask, dtype=bool)
    errors = flip_map(ref, test, tonemap=tonemap, exposure=exposure)
    if mask.shape != errors.shape:
        raise InputError(f"masked_flip: mask has shape {mask.shape}, expected the images' {errors.shape}")
    return float(errors[mask].mean(dtype=np.float64)) if mask.any() else math.nan


def hdr_flip(ref, test) -> float:
    """Mean HDR-FLIP between linear images (H, W, 3); negatives are clamped to 0.

    HDR-FLIP picks its exposure range from the reference; for an all-black reference the range of
    the test image is used instead (0 when both are black).
    """
    ref, test = _image_pair(ref, test)
    ref, test = np.maximum(ref, 0.0), np.maximum(test, 0.0)
    parameters = {}
    if not ref.any():
        if not test.any():
            return 0.0
        parameters = _flip(test, test, "HDR")[2]
    return float(_flip(ref, test, "HDR", parameters)[1])


def _image_pair(ref, test) -> tuple[np.ndarray, np.ndarray]:
    ref = image_to_numpy(ref, "ref")
    test = image_to_numpy(test, "test")
    if ref.shape != test.shape:
        raise InputError(f"images differ in shape: ref {ref.shape}, test {test.shape}")
    return ref, test


def _check_flip_input(img: np.ndarray, name: str, ldr: bool) -> None:
    """flip-evaluator exits the interpreter on bad input, so everything it assumes is checked here."""
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.float32 or not img.flags.c_contiguous:
        raise InputError(f"FLIP {name}: expected a contiguous float32 (H, W, 3) array, "
                         f"got {img.dtype} {tuple(img.shape)}")
    if not np.isfinite(img).all():
        raise InputError(f"FLIP {name}: non-finite values")
    lo, hi = float(img.min()), float(img.max())
    if lo < 0 or (ldr and hi > 1):
        raise InputError(f"FLIP {name}: values must lie in {'[0, 1]' if ldr else '[0, inf)'}, got [{lo:.4g}, {hi:.4g}]")


def _flip(ref: np.ndarray, test: np.ndarray, dynamic_range: str, parameters: dict | None = None):
    """flip_evaluator.evaluate after validation: (error map (H, W, 1), mean, parameters used)."""
    import flip_evaluator

    ref, test = np.ascontiguousarray(ref, np.float32), np.ascontiguousarray(test, np.float32)
    _check_flip_input(ref, "ref", ldr=dynamic_range == "LDR")
    _check_flip_input(test, "test", ldr=dynamic_range == "LDR")
    if ref.shape != test.shape:
        raise InputError(f"FLIP: images differ in shape: ref {ref.shape}, test {test.shape}")
    return flip_evaluator.evaluate(ref, test, dynamic_range, applyMagma=False, parameters=dict(parameters or {}))


def _ldr_flip(ref_srgb: np.ndarray, test_srgb: np.ndarray) -> np.ndarray:
    """LDR-FLIP error map (H, W) of two sRGB images in [0, 1]."""
    return _flip(ref_srgb, test_srgb, "LDR")[0][:, :, 0]


def _ssim(ref_srgb: np.ndarray, test_srgb: np.ndarray) -> float:
    from skimage.metrics import structural_similarity

    return float(structural_similarity(ref_srgb, test_srgb, data_range=1.0, channel_axis=2))
