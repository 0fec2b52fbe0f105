"""Side-by-side comparison pictures: one row per model, "reference | model | FLIP error map" (`compare_image`), and
the one-row picture of an image comparison with its noise floor's error beside (`comparison_picture`)."""
from __future__ import annotations

import math
import numbers

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from ..core.errors import InputError
from ..io.images import image_to_numpy
from ..metrics.image import flip_map
from ..color.tonemap import to_ldr

#: panels narrower than this many pixels are enlarged by an integer factor (nearest neighbour)
MIN_PANEL_WIDTH = 160
PAD = 4
BACKGROUND = (32, 32, 32)
TEXT = (235, 235, 235)
FONT_SIZE = 12


def compare_image(ref, others: dict, metrics: dict | None = None, tonemap: str = "clip",
                  exposure: float = 0.0) -> np.ndarray:
    """Comparison picture (H', W', 3) uint8 of linear images (H, W, 3) (numpy or torch).

    One row per entry of `others` (name -> image): the tone-mapped reference, the tone-mapped model
    and its LDR-FLIP error map (magma colour map, 0 black .. 1 white-yellow), with labels above and
    the metric values below: `metrics[name]` (name -> {metric: value}) if given, else the mean FLIP.
    """
    from matplotlib import colormaps

    if not others:
        raise InputError("compare_image: `others` is empty; give at least one model image")
    ref = image_to_numpy(ref, "compare_image: ref")
    ref_ldr = _to_uint8(to_ldr(ref, exposure=exposure, tonemap=tonemap))
    scale = max(1, math.ceil(MIN_PANEL_WIDTH / ref.shape[1]))
    font = ImageFont.load_default(size=FONT_SIZE)
    rows = []
    for name, img in others.items():
        img = image_to_numpy(img, f"compare_image: others[{name!r}]")
        if img.shape != ref.shape:
            raise InputError(f"compare_image: others[{name!r}] has shape {img.shape}, the reference {ref.shape}")
        error = flip_map(ref, img, tonemap=tonemap, exposure=exposure)
        if metrics is not None and name in metrics:
            values = metrics[name]
        else:
            values = {"flip": float(error.mean())}
        panels = [ref_ldr, _to_uint8(to_ldr(img, exposure=exposure, tonemap=tonemap)),
                  _to_uint8(colormaps["magma"](error)[:, :, :3])]
        rows.append(_row([_enlarge(p, scale) for p in panels], ["reference", str(name), "FLIP error"],
                         _format_metrics(values), font))
    return np.concatenate(rows, axis=0)


def comparison_picture(renders: tuple, test, name: str, scores: dict[str, float],
                       shown: tuple[str, ...] = ("flip", "ssim", "mae"), tonemap: str = "clip") -> np.ndarray:
    """The picture of one `neumat.render.comparison.image_comparison`, one row: the reference | `name`'s rendering
    `test` | its FLIP error | the FLIP error of the reference rendered like the model (the floor: what noise alone
    gives), with the `shown` scores of both below (`scores` holds them and "floor_" + each); `renders` are
    `reference_renders`'. Rows of one source stack into a table's figure (the same width)."""
    from matplotlib import colormaps

    ref = image_to_numpy(renders[0], "comparison_picture: reference")
    scale = max(1, math.ceil(MIN_PANEL_WIDTH / ref.shape[1]))
    panels = [_to_uint8(to_ldr(ref, tonemap=tonemap)),
              _to_uint8(to_ldr(image_to_numpy(test, "comparison_picture: test"), tonemap=tonemap))]
    for img in (test, renders[1]):
        panels.append(_to_uint8(colormaps["magma"](flip_map(ref, img, tonemap=tonemap))[:, :, :3]))
    items = _format_metrics({k: scores[k] for k in shown}) + \
        ["floor: " + "  ".join(_format_metrics({k: scores[f"floor_{k}"] for k in shown}))]
    return _row([_enlarge(p, scale) for p in panels], ["reference", name, "FLIP error", "floor's FLIP error"], items,
                ImageFont.load_default(size=FONT_SIZE))


def _to_uint8(x: np.ndarray) -> np.ndarray:
    return np.round(np.clip(x, 0.0, 1.0) * 255.0).astype(np.uint8)


def _enlarge(img: np.ndarray, scale: int) -> np.ndarray:
    return img.repeat(scale, axis=0).repeat(scale, axis=1) if scale > 1 else img


def _format_metrics(values: dict) -> list[str]:
    """'name=value' items, numbers with 4 significant digits."""
    return [f"{k}={v:.4g}" if isinstance(v, numbers.Real) else f"{k}={v}" for k, v in values.items()]


def _wrap(items: list[str], font, width: int) -> list[str]:
    """Join items with spaces into lines no wider than `width` pixels (an item is never split)."""
    lines: list[str] = []
    for item in items:
        if lines and font.getlength(lines[-1] + "   " + item) <= width:
            lines[-1] += "   " + item
        else:
            lines.append(item)
    return lines


def label_lines(label: str, font, width: int) -> list[str]:
    """A panel's label as lines no wider than `width` pixels (split at spaces; a word wider than the panel is
    split where it overflows), so that a long model name does not run over the next panel's label."""
    lines: list[str] = []
    for word in label.split(" "):
        if lines and font.getlength(lines[-1] + " " + word) <= width:
            lines[-1] += " " + word
            continue
        while font.getlength(word) > width and len(word) > 1:
            cut = 1  # the longest prefix that fits (at least one character)
            while cut < len(word) and font.getlength(word[:cut + 1]) <= width:
                cut += 1
            lines.append(word[:cut])
            word = word[cut:]
        lines.append(word)
    return lines


def _row(panels: list[np.ndarray], labels: list[str], items: list[str], font) -> np.ndarray:
    """Panels side by side with a label above each (wrapped to its panel's width) and the wrapped metric items
    below."""
    h, w = panels[0].shape[:2]
    line_h = font.getbbox("Ag")[3] + 4
    width = len(panels) * w + (len(panels) + 1) * PAD
    lines = _wrap(items, font, width - 2 * PAD)
    label_rows = [label_lines(label, font, w) for label in labels]
    top = max(len(rows) for rows in label_rows) * line_h
    height = PAD + top + h + PAD + len(lines) * line_h + PAD
    canvas = Image.new("RGB", (width, height), BACKGROUND)
    draw = ImageDraw.Draw(canvas)
    for k, (panel, rows) in enumerate(zip(panels, label_rows)):
        x = PAD + k * (w + PAD)
        for j, text in enumerate(rows):
            draw.text((x, PAD + j * line_h), text, fill=TEXT, font=font)
        canvas.paste(Image.fromarray(panel), (x, PAD + top))
    for k, line in enumerate(lines):
        draw.text((PAD, PAD + top + h + PAD + k * line_h), line, fill=TEXT, font=font)
    return np.asarray(canvas)
