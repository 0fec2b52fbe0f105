"""Linear HDR -> display sRGB: exposure, a named tone curve, and the sRGB transfer functions.

Every function accepts a numpy array or a torch tensor and returns the same kind, shape and dtype.
"""
from __future__ import annotations

import difflib

import numpy as np
import torch

from ..core.errors import UnknownNameError

#: Rec. 709 luminance weights of linear RGB
LUMINANCE = (0.2126, 0.7152, 0.0722)


def _xp(x):
    """The array module (torch or numpy) that `x` belongs to."""
    return torch if isinstance(x, torch.Tensor) else np


def srgb_encode(linear):
    """sRGB OETF (IEC 61966-2-1) of linear values in [0, 1]:
    12.92 x for x <= 0.0031308, else 1.055 x^(1/2.4) - 0.055. Inputs are clamped to [0, 1] first."""
    x = linear.clip(0.0, 1.0)
    return _xp(x).where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)


def srgb_decode(encoded):
    """Inverse of `srgb_encode` on [0, 1]: x / 12.92 for x <= 0.04045, else ((x + 0.055) / 1.055)^2.4."""
    x = encoded.clip(0.0, 1.0)
    return _xp(x).where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


def srgb_to_linear(x: np.ndarray) -> np.ndarray:
    """sRGB transfer function inverse (IEC 61966-2-1) of values in [0, 1], without `srgb_decode`'s clamp."""
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


def _clip(x):
    return x.clip(0.0, 1.0)


def _reinhard(x):
    """Reinhard et al. 2002 global operator per channel: x / (1 + x)."""
    x = x.clip(min=0.0)
    return x / (1.0 + x)


def _aces(x):
    """Narkowicz 2015 fit of the ACES filmic curve per channel (no 0.6 pre-exposure):
    x (2.51 x + 0.03) / (x (2.43 x + 0.59) + 0.14), clamped to [0, 1]."""
    x = x.clip(min=0.0)
    return (x * (2.51 * x + 0.03) / (x * (2.43 * x + 0.59) + 0.14)).clip(0.0, 1.0)


#: tone curves: linear radiance (>= 0, after exposure) -> linear display value in [0, 1]
TONEMAPS = {"clip": _clip, "reinhard": _reinhard, "aces": _aces}


def to_ldr(img, exposure: float = 0.0, tonemap: str = "clip"):
    """Linear RGB image (H, W, 3) -> display sRGB in [0, 1].

    The image is scaled by 2**exposure (stops), mapped to [0, 1] by the tone curve `tonemap`
    ("clip": clamp; "reinhard": x / (1 + x); "aces": Narkowicz's ACES fit) and sRGB-encoded.
    """
    if tonemap not in TONEMAPS:
        close = difflib.get_close_matches(tonemap, TONEMAPS, n=2)
        hint = f"; did you mean {', '.join(close)}?" if close else ""
        raise UnknownNameError(f"unknown tonemap {tonemap!r}{hint} (known: {', '.join(TONEMAPS)})")
    return srgb_encode(TONEMAPS[tonemap](img * float(2.0 ** exposure)))
