"""Shared by the docs/ picture scripts: a labelled, tone-mapped image tile and a grid of tiles written to
docs/images."""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import torch
from PIL import Image, ImageDraw, ImageFont

from neumat.color.tonemap import to_ldr

IMAGES = Path(__file__).resolve().parent / "images"


def labelled_tile(radiance: torch.Tensor, label: str, exposure: float = 0.0, magnify: int = 1) -> np.ndarray:
    """radiance (H, W, 3) tone-mapped to 8-bit sRGB (`to_ldr`, `exposure` stops), magnified `magnify` times
    (nearest), with `label` in yellow at the top left: (magnify H, magnify W, 3) uint8."""
    tile = Image.fromarray(np.round(to_ldr(radiance.numpy(), exposure=exposure) * 255).astype(np.uint8))
    if magnify != 1:
        tile = tile.resize((magnify * tile.width, magnify * tile.height), Image.NEAREST)
    ImageDraw.Draw(tile).text((3, 2), label, fill=(255, 255, 0), font=ImageFont.load_default(size=13))
    return np.asarray(tile)


def save_grid(rows: list[list[np.ndarray]], name: str, started: float) -> Path:
    """Write the rows of tiles as docs/images/<name>.png and say so with the seconds since `started`."""
    out = IMAGES / f"{name}.png"
    Image.fromarray(np.concatenate([np.concatenate(row, axis=1) for row in rows], axis=0)).save(out)
    print(f"wrote {out} in {time.perf_counter() - started:.0f} s")
    return out
