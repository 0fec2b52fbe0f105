"""The web viewer: the page embeds the export exactly, and in headless Chromium (SwiftShader WebGL 2) it renders
what the torch model gives in the same scene (`neumat.export.web.scene`)."""
import base64
import json
import re

import numpy as np
import pytest
import torch

from neumat.core.errors import InputError
from neumat.export.glsl import export_glsl
from neumat.export.web.headless import chromium, viewer_pixels, viewer_screenshot
from neumat.export.web.scene import View, viewer_image, viewer_queries
from neumat.export.web.viewer import viewer_html, write_viewer
from neumat.models.half_precision import half_rounded
from neumat.methods.neubrdf.model import NeuBRDF
from neumat.models.registry import build_model

needs_browser = pytest.mark.skipif(chromium() is None, reason="no chromium on PATH (Debian: apt-get install chromium)")


def _perturbed(model, scale: float = 0.1, seed: int = 1):
    torch.manual_seed(seed)
    with torch.no_grad():
        for p in model.parameters():
            p.add_(scale * torch.randn_like(p))
    return model.train(False)


def _embedded(page: str) -> dict:
    return json.loads(re.search(r"const DATA = (\{.*?\});\n", page, re.S).group(1))


@pytest.mark.parametrize("precision", ["fp16", "fp32"])
def test_page_embeds_source_and_textures_exactly(precision):
    """Every texture embedded bit for bit at the export's precision (an fp16 export's halves stay halves)."""
    model = build_model({"type": "multiscale", "spatial_size": 8}).train(False)
    shader = export_glsl(model, precision=precision)
    page = viewer_html(shader, "gated <test>")
    assert "<title>neumat viewer: gated &lt;test&gt;</title>" in page
    assert shader.source in page and "nm_viewer_eval(vec3 wi, vec3 wo, vec2 uv, mat2 footprint)" in page
    textures = _embedded(page)["textures"]
    assert sorted(textures) == sorted(shader.textures)
    for name, data in shader.textures.items():
        entry = textures[name]
        assert (entry["layers"], entry["height"], entry["width"]) == data.shape[:3]
        half = precision == "fp16" and name not in shader.exact
        assert entry["format"] == ("RGBA16F" if half else "RGBA32F") and data.dtype == (np.float16 if half else
                                                                                          np.float32)
        decoded = np.frombuffer(base64.b64decode(entry["data"]), "<f2" if half else "<f4").reshape(data.shape)
        assert np.array_equal(decoded, data)


def test_bad_input_is_refused(tmp_path):
    model = build_model({"type": "multiscale", "homogeneous": True}).train(False)
    with pytest.raises(InputError, match=r"\.html"):
        write_viewer(model, tmp_path / "viewer.txt")
    neupress = build_model({"type": "neupress", "width": 8, "layers": 2})
    neupress.set_bounds(torch.tensor([-1.0, -1.0, -1.0]), torch.tensor([1.0, 1.0, 1.0]))
    with pytest.raises(InputError, match="no BRDF entry point"):
        write_viewer(neupress, tmp_path / "n.html")
    with pytest.raises(InputError, match="shape"):
        viewer_queries(View(shape="cube"), 8, 8)
    with pytest.raises(InputError, match="no page"):
        viewer_pixels(tmp_path / "missing.html", View(), 8, 8)


def test_scene_matches_closed_forms_facing_the_camera():
    light = torch.tensor([np.cos(0.9) * np.cos(0.8), np.cos(0.9) * np.sin(0.8), np.sin(0.9)], dtype=torch.float32)
    # plane facing the camera: the local frame is the view frame, uv is linear in the pixel position
    q, valid = viewer_queries(View(shape="plane", yaw=0.0, pitch=0.0, tiles=3.0), 20, 20)
    p = 1.25 * (2 * (torch.arange(20) + 0.5) - 20) / 20
    assert int(valid.sum()) == int(((p.abs() < 0.8).sum()) ** 2)
    assert torch.allclose(q.wi[valid], light.expand(int(valid.sum()), 3), atol=1e-6)
    assert torch.allclose(q.wo[valid], torch.tensor([0.0, 0.0, 1.0]).expand(int(valid.sum()), 3))
    u = (p / 1.6 + 0.5) * 3.0
    assert torch.allclose(q.uv.view(20, 20, 2)[:, :, 0], u.expand(20, 20), atol=1e-6)
    assert torch.allclose(q.uv.view(20, 20, 2)[:, :, 1], u.flip(0).unsqueeze(1).expand(20, 20), atol=1e-6)
    # sphere facing the camera: cos(theta_o) = n_z, cos(theta_i) = n . light, v = latitude / pi + 1/2
    q, valid = viewer_queries(View(yaw=0.0, pitch=0.0), 20, 20)
    x, y = p.expand(20, 20), p.flip(0).unsqueeze(1).expand(20, 20)
    nz = (1 - x * x - y * y).clamp(min=0).sqrt()
    n = torch.stack([x, y, nz], -1).view(-1, 3)
    on = valid & (n[:, 2] > 0.05)
    assert torch.allclose(q.wo[on, 2], n[on, 2], atol=1e-6)
    assert torch.allclose(q.wi[on, 2], n[on] @ light, atol=1e-6)
    latitude = torch.atan2(n[:, 2], n[:, :2].norm(dim=-1))
    assert torch.allclose(q.uv[on, 1], latitude[on] / np.pi + 0.5, atol=1e-6)


SCENES = {
    "multiscale-homogeneous-sphere": (lambda: _perturbed(build_model({"type": "multiscale", "homogeneous": True})),
                                      View()),
    "neubrdf-sphere-light-low": (lambda: _perturbed(NeuBRDF(nside=8, feature_dim=8, index_bits=5, hidden=16), 0.3),
                                 View(elevation=0.3, azimuth=2.5, exposure=1.0)),
    "neubrdf-first-layer-table": (lambda: _perturbed(NeuBRDF(nside=8, feature_dim=8, index_bits=5, hidden=16,
                                                             interpolation="uniform"), 0.3),
                                  View(elevation=0.5, azimuth=2.0, exposure=1.0)),
    "neubrdf-direction-inputs": (lambda: _perturbed(NeuBRDF(nside=8, feature_dim=8, index_bits=5, hidden=16,
                                                            direction_inputs="hd_warp"), 0.3),
                                 View(elevation=0.6, azimuth=1.0, exposure=1.0)),
    "neubrdf-texture-plane": (lambda: _perturbed(NeuBRDF(nside=8, feature_dim=8, index_bits=5, hidden=16,
                                                         texture_height=8, texture_width=8, texture_channels=4), 0.3),
                              View(shape="plane", tiles=2.0)),
}


@needs_browser
@pytest.mark.parametrize("name", SCENES)
def test_page_renders_what_torch_renders(name, tmp_path):
    make, view = SCENES[name]
    model = make()
    page = write_viewer(model, tmp_path / "viewer.html")  # the default fp16 export: torch with halves stored
    pixels = viewer_pixels(page, view, 40, 32)
    reference = viewer_image(half_rounded(model), view, 40, 32)
    covered = reference.amax(-1) > 0
    assert covered.float().mean() > 0.1  # the object is in the picture
    assert torch.isfinite(pixels).all()
    error = (pixels[..., :3] - reference).abs() / reference.abs().clamp(min=1e-3 * float(reference.max()))
    assert float(error.max()) < 1e-3, f"{name}: max relative difference {float(error.max()):.2e}"


@needs_browser
def test_sparse_btf_page_matches_torch(tmp_path):
    from btf_util import synthetic_btf
    from neumat.methods.sparse_btf.model import SparseBTF
    from neumat.methods.sparse_btf.dictionary_train import train_dictionary

    dictionary = train_dictionary([synthetic_btf(s) for s in (1, 2)], num_dictionaries=2, tau_train=(16, 4, 4),
                                  patch=4, max_iters=2)
    model = SparseBTF.encode(synthetic_btf(3), dictionary, (32, 8, 8))
    view = View(shape="plane", pitch=-0.5, elevation=1.1)
    page = write_viewer(model, tmp_path / "btf.html")
    pixels, reference = viewer_pixels(page, view, 40, 32)[..., :3], viewer_image(model, view, 40, 32)
    error = (pixels - reference).abs() / reference.abs().clamp(min=1e-3 * float(reference.max()))
    # k-nearest bin interpolation jumps where two bins are equally near; float rounding may pick either bin
    assert float((error > 1e-3).float().mean()) < 0.01
    assert float(error.median()) < 1e-5


@needs_browser
def test_filtered_export_compiles_and_renders_near_its_finest_level(tmp_path):
    """neural-appearance filters its latent pyramid by the page's dFdx / dFdy footprint, which the torch scene
    does not model: at 1 / 8 texel per pixel the filter stays at the finest level and the images agree."""
    model = _perturbed(build_model({"type": "neural-appearance", "spatial_size": 8}))
    view = View(shape="plane")
    page = write_viewer(model, tmp_path / "na.html")
    pixels, reference = viewer_pixels(page, view, 96, 96)[..., :3], viewer_image(half_rounded(model), view, 96, 96)
    covered = reference.amax(-1) > 0
    error = (pixels - reference).abs()[covered] / reference[covered].abs().clamp(min=1e-6)
    assert float(error.median()) < 1e-3, f"median relative difference {float(error.median()):.2e}"


@needs_browser
def test_screenshot_of_the_interactive_page(tmp_path):
    page = write_viewer(_perturbed(build_model({"type": "multiscale", "homogeneous": True})), tmp_path / "v.html")
    png = viewer_screenshot(page, tmp_path / "v.png", View(shape="plane"), width=320, height=240)
    from PIL import Image

    image = np.asarray(Image.open(png).convert("RGB"), dtype=np.float32)
    assert image.shape == (240, 320, 3)
    assert image.std() > 5  # the material and the panel, not a blank page
