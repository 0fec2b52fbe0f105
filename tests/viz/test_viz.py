"""Pictures: comparison strips, BRDF slices, polar plots and the HTML report."""
from __future__ import annotations

import base64
import io
import math
import re

import numpy as np
import pytest
import torch
from PIL import Image

from neumat import Material
from neumat.core.errors import InputError
from neumat.io.images import read_image, write_image_ldr
from neumat.viz import brdf_slice_image, compare_image, polar_plot, write_report
from neumat.viz.slices import brdf_slice_range
from neumat.viz.compare import MIN_PANEL_WIDTH, PAD


class Phong(Material):
    """Normalised Phong lobe plus a coloured diffuse term (test only)."""

    name = "phong"

    def eval(self, q):
        r = torch.stack([-q.wi[:, 0], -q.wi[:, 1], q.wi[:, 2]], -1)
        lobe = (r * q.wo).sum(-1).clamp(min=0) ** 20 * 22 / (2 * math.pi)
        return torch.tensor([0.2, 0.4, 0.6]).to(q.wi) / math.pi + lobe[:, None]


class DimPhong(Phong):
    """Phong at a tenth of the value (test only); the same name, so the same plot title."""

    def eval(self, q):
        return super().eval(q) * 0.1


class Checker(Material):
    """Spatially varying constant (test only): 0.1 or 0.5 by uv checker."""

    name = "checker"
    spatially_varying = True

    def eval(self, q):
        q.require("uv", who="Checker")
        cell = ((q.uv * 4).floor().sum(-1) % 2)[:, None]
        return (0.1 + 0.4 * cell).expand(len(q), 3)


def gradient(h=24, w=32) -> np.ndarray:
    yy, xx = np.meshgrid(np.linspace(0, 1, h), np.linspace(0, 1, w), indexing="ij")
    return np.stack([xx, yy, 0.5 * xx * yy], -1).astype(np.float32)


def test_compare_image_layout_and_flip_panel(tmp_path):
    ref = gradient()
    others = {"same": torch.from_numpy(ref.copy()), "darker": ref * 0.5}
    pic = compare_image(ref, others)
    assert pic.dtype == np.uint8 and pic.ndim == 3 and pic.shape[2] == 3
    scale = math.ceil(MIN_PANEL_WIDTH / ref.shape[1])
    w = ref.shape[1] * scale
    assert pic.shape[1] == 3 * w + 4 * PAD
    row_h = pic.shape[0] // 2
    assert pic.shape[0] == 2 * row_h
    # the first row compares identical images: its FLIP panel is magma(0), nearly black
    first = pic[:row_h, PAD + 2 * (w + PAD): PAD + 3 * w + 2 * PAD]
    panel = first[row_h // 2 - 10: row_h // 2 + 10]
    assert panel.max() < 10
    second = pic[row_h:, PAD + 2 * (w + PAD): PAD + 3 * w + 2 * PAD]
    assert second[row_h // 2 - 10: row_h // 2 + 10].mean() > panel.mean() + 20
    write_image_ldr(tmp_path / "cmp.png", pic)                 # what `neumat compare -o` does
    assert read_image(tmp_path / "cmp.png").shape == pic.shape


def test_compare_image_writes_given_metrics():
    ref = gradient()
    plain = compare_image(ref, {"m": ref * 0.9})
    many = {"m": {"flip": 0.1234567, "ssim": np.float32(0.9), "psnr": 31.0, "rmse": 0.01, "mae": 0.005,
                  "hdr_flip": 0.2, "rmse_hdr": 1e-3, "mae_hdr": 4e-4, "rel_err": 0.05, "log_err": 0.01}}
    annotated = compare_image(ref, {"m": ref * 0.9}, metrics=many)
    assert annotated.shape[1] == plain.shape[1] and annotated.shape[0] > plain.shape[0]   # wrapped lines


def test_compare_image_wraps_a_long_label_within_its_panel():
    """A model name wider than its panel wraps onto more lines above the panels instead of running over the FLIP
    panel's label: every line fits the panel's width, the words are kept, and the row grows by whole lines."""
    from PIL import ImageFont

    from neumat.viz.compare import FONT_SIZE, label_lines

    font = ImageFont.load_default(size=FONT_SIZE)
    name = "today (1000 views x 64 paths, the paper's model) and_a_single_word_wider_than_any_panel_of_this_picture"
    lines = label_lines(name, font, 120)
    assert len(lines) >= 3 and all(font.getlength(line) <= 120 for line in lines), lines
    assert "".join(lines).replace(" ", "") == name.replace(" ", "")
    ref = gradient()
    short, long = compare_image(ref, {"m": ref * 0.9}), compare_image(ref, {name: ref * 0.9})
    scale = math.ceil(MIN_PANEL_WIDTH / ref.shape[1])
    extra = len(label_lines(name, font, ref.shape[1] * scale)) - 1
    line_h = font.getbbox("Ag")[3] + 4
    assert long.shape[1] == short.shape[1] and long.shape[0] == short.shape[0] + extra * line_h and extra >= 1


def test_compare_image_errors():
    ref = gradient()
    with pytest.raises(InputError, match="empty"):
        compare_image(ref, {})
    with pytest.raises(InputError, match="has shape"):
        compare_image(ref, {"m": gradient(24, 30)})
    bad = ref.copy()
    bad[0, 0, 0] = np.nan
    with pytest.raises(InputError, match="non-finite"):
        compare_image(ref, {"m": bad})


def test_brdf_slice_image():
    rgb = brdf_slice_image(Phong(), resolution=30)
    lum = brdf_slice_image(Phong(), resolution=30, channels="luminance")
    assert rgb.dtype == np.uint8 and rgb.ndim == 3 and rgb.shape[2] == 3
    assert lum.dtype == np.uint8 and lum.shape[0] == rgb.shape[0] and lum.shape[1] * 2 < rgb.shape[1]
    assert rgb.std() > 10                                     # something was drawn
    assert brdf_slice_image(Checker(), resolution=8, channels="luminance").shape == lum.shape
    with pytest.raises(InputError, match="channels"):
        brdf_slice_image(Phong(), channels="xyz")
    with pytest.raises(InputError, match="resolution"):
        brdf_slice_image(Phong(), resolution=1)


def test_brdf_slices_on_one_shared_scale():
    # each slice on its own scale: a material and a tenth of it differ only in the colour bars' labels; on one
    # scale the slices themselves differ
    def changed(a, b):
        return float((np.abs(a.astype(int) - b) > 30).any(-1).mean())
    own = changed(brdf_slice_image(Phong(), resolution=20), brdf_slice_image(DimPhong(), resolution=20))
    vmin, vmax = brdf_slice_range([Phong(), DimPhong()], decades=3, resolution=20)
    assert vmin == pytest.approx(vmax * 1e-3)
    bright = brdf_slice_image(Phong(), resolution=20, value_range=(vmin, vmax))
    dim = brdf_slice_image(DimPhong(), resolution=20, value_range=(vmin, vmax))
    assert own < 0.01 and changed(bright, dim) > 0.2, (own, changed(bright, dim))
    with pytest.raises(InputError, match="value_range"):
        brdf_slice_image(Phong(), value_range=(1.0, 0.5))


def test_polar_plot():
    pic = polar_plot({"phong": Phong(), "checker": Checker()}, theta_i_deg=(20, 60), resolution=61)
    assert pic.dtype == np.uint8 and pic.ndim == 3 and pic.shape[2] == 3 and pic.std() > 10
    one = polar_plot({"phong": Phong()}, theta_i_deg=(45,), resolution=31)
    assert one.shape[1] < pic.shape[1]
    with pytest.raises(InputError, match="empty"):
        polar_plot({})
    with pytest.raises(InputError, match="theta_i_deg"):
        polar_plot({"phong": Phong()}, theta_i_deg=(95,))
    with pytest.raises(InputError, match="decades"):
        polar_plot({"phong": Phong()}, decades=0)


def test_write_report(tmp_path):
    a = np.zeros((4, 5, 3), np.uint8)
    b = np.full((6, 3, 3), 200, np.uint8)
    sections = [
        {"heading": "Renders <&>", "text": "First paragraph.\n\nSecond one.",
         "images": [("reference", a), ("model <b>", b)]},
        {"heading": "Numbers", "table": [{"material": "x", "flip": 0.123456, "n": 3},
                                         {"material": "y", "psnr": float("inf")}]},
    ]
    path = write_report(tmp_path / "out" / "report.html", "Report & summary", sections)
    text = path.read_text(encoding="utf-8")
    assert text.startswith("<!DOCTYPE html>") and text.rstrip().endswith("</html>")
    assert "<title>Report &amp; summary</title>" in text
    for heading in ("Renders &lt;&amp;&gt;", "Numbers"):
        assert f"<h2>{heading}</h2>" in text
    for caption in ("reference", "model &lt;b&gt;"):
        assert f"<figcaption>{caption}</figcaption>" in text
    assert text.count("<p>") == 2
    payloads = re.findall(r'<img src="data:image/png;base64,([A-Za-z0-9+/=]+)"', text)
    assert len(payloads) == 2
    for payload, img in zip(payloads, (a, b)):
        assert np.array_equal(np.asarray(Image.open(io.BytesIO(base64.b64decode(payload)))), img)
    assert "<th>material</th><th>flip</th><th>n</th><th>psnr</th>" in text
    assert "<td>0.1235</td>" in text and "<td>3</td>" in text and "<td>inf</td>" in text


def test_write_report_errors(tmp_path):
    with pytest.raises(InputError, match="heading"):
        write_report(tmp_path / "r.html", "t", [{"text": "no heading"}])
    with pytest.raises(InputError, match="unknown key"):
        write_report(tmp_path / "r.html", "t", [{"heading": "h", "image": []}])
    with pytest.raises(InputError, match="uint8"):
        write_report(tmp_path / "r.html", "t", [{"heading": "h", "images": [("c", np.zeros((2, 2, 3)))]}])
