"""Run the web viewer in headless Chromium (SwiftShader WebGL 2 on the CPU): linear pixels or a screenshot."""
from __future__ import annotations

import base64
import json
import re
import shutil
import subprocess
import urllib.parse
from pathlib import Path

import numpy as np
import torch

from ...core.errors import InputError
from .scene import View

BROWSERS = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")
FLAGS = ["--headless", "--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
         "--disable-dev-shm-usage", "--hide-scrollbars"]


def chromium() -> str | None:
    """Path of a Chromium-family browser on PATH, or None."""
    for name in BROWSERS:
        found = shutil.which(name)
        if found:
            return found
    return None


def _browser() -> str:
    found = chromium()
    if found is None:
        raise InputError(f"no headless browser found (looked for {', '.join(BROWSERS)} on PATH)")
    return found


def _url(page: Path, view: View, width: int, height: int) -> str:
    state = {**view.page_state(), "width": width, "height": height}
    return page.resolve().as_uri() + "#test=" + urllib.parse.quote(json.dumps(state))


def viewer_pixels(page: str | Path, view: View, width: int, height: int, timeout: float = 180.0) -> torch.Tensor:
    """Linear RGBA values (H, W, 4) float32, top row first, of the viewer page `page` (from `write_viewer`)
    rendering `view` into a float framebuffer in headless Chromium. Raises InputError with the page's message
    when the shader does not compile or the GPU lacks something."""
    page = Path(page)
    if not page.is_file():
        raise InputError(f"viewer_pixels: no page at {str(page)!r}")
    if width < 1 or height < 1:
        raise InputError(f"viewer_pixels: expected a positive size, got {width} x {height}")
    run = subprocess.run([_browser(), *FLAGS, "--dump-dom", "--virtual-time-budget=60000",
                          _url(page, view, width, height)], capture_output=True, text=True, timeout=timeout)
    error = re.search(r'<pre id="neumat-error">(.*?)</pre>', run.stdout, re.S)
    if error and error.group(1).strip():
        raise InputError(f"viewer page {page.name}: {error.group(1).strip()}")
    found = re.search(r'<pre id="neumat-pixels"[^>]*>([A-Za-z0-9+/=]*)</pre>', run.stdout)
    if not found or not found.group(1):
        raise InputError(f"viewer page {page.name} wrote no pixels (browser exit {run.returncode}): "
                         f"{run.stderr.strip()[-500:]}")
    values = np.frombuffer(base64.b64decode(found.group(1)), np.float32)
    if values.size != width * height * 4:
        raise InputError(f"viewer page {page.name}: expected {width * height * 4} values, got {values.size}")
    return torch.from_numpy(values.reshape(height, width, 4)[::-1].copy())


def viewer_screenshot(page: str | Path, png: str | Path, view: View | None = None, width: int = 640,
                      height: int = 480, timeout: float = 180.0) -> Path:
    """Save a PNG screenshot of the interactive page (panel included) at `view` (default: the page's own)."""
    page, png = Path(page), Path(png)
    if not page.is_file():
        raise InputError(f"viewer_screenshot: no page at {str(page)!r}")
    url = page.resolve().as_uri()
    if view is not None:
        url += "#view=" + urllib.parse.quote(json.dumps(view.page_state()))
    png.parent.mkdir(parents=True, exist_ok=True)
    subprocess.run([_browser(), *FLAGS, f"--screenshot={png.resolve()}", f"--window-size={width},{height}",
                    "--virtual-time-budget=60000", url], capture_output=True, timeout=timeout)
    if not png.is_file():
        raise InputError(f"viewer_screenshot: the browser wrote no {png}")
    return png
