import math

import numpy as np
import pytest
import torch
from PIL import Image

from neumat.core.errors import DataFormatError, InputError
from neumat.color.tonemap import srgb_to_linear
from neumat.io.texture_set import load_texture_set, normals_from_height


def _write(folder, name, array):
    Image.fromarray(np.asarray(array, dtype=np.uint8)).save(folder / name)


def _synthetic_set(folder, size=(8, 12), normal=True, dx=False):
    h, w = size
    rng = np.random.default_rng(0)
    _write(folder, "Test_1K-JPG_Color.png", rng.integers(0, 256, (h, w, 3)))
    _write(folder, "Test_1K-JPG_Roughness.png", rng.integers(0, 256, (h, w)))
    _write(folder, "Test_1K-JPG_Displacement.png", rng.integers(0, 256, (h, w)))
    if normal:
        n = np.zeros((h, w, 3))
        n[..., 0], n[..., 1], n[..., 2] = 0.3, 0.4, math.sqrt(1 - 0.25)
        if dx:
            n[..., 1] *= -1
        _write(folder, f"Test_1K-JPG_Normal{'DX' if dx else 'GL'}.png", np.round((n + 1) / 2 * 255))
    return folder


def test_synthetic_set_decodes_every_map(tmp_path):
    _synthetic_set(tmp_path)
    ts = load_texture_set(tmp_path)
    raw = np.asarray(Image.open(tmp_path / "Test_1K-JPG_Color.png"), dtype=np.float32) / 255
    assert ts.size == (8, 12) and ts.color.dtype == torch.float32
    np.testing.assert_allclose(ts.color.numpy(), srgb_to_linear(raw), atol=1e-6)
    rough = np.asarray(Image.open(tmp_path / "Test_1K-JPG_Roughness.png"), dtype=np.float32) / 255
    np.testing.assert_allclose(ts.roughness.numpy(), rough, atol=1e-6)
    assert torch.equal(ts.metalness, torch.zeros(8, 12))
    assert not ts.normal_from_height
    torch.testing.assert_close(ts.normal.norm(dim=-1), torch.ones(8, 12))
    torch.testing.assert_close(ts.normal[0, 0], torch.tensor([0.3, 0.4, math.sqrt(0.75)]), atol=6e-3, rtol=0)


def test_directx_normal_map_is_flipped_to_opengl(tmp_path):
    (tmp_path / "gl").mkdir()
    (tmp_path / "dx").mkdir()
    gl = load_texture_set(_synthetic_set(tmp_path / "gl", dx=False))
    dx = load_texture_set(_synthetic_set(tmp_path / "dx", dx=True))
    torch.testing.assert_close(dx.normal, gl.normal, atol=1e-2, rtol=0)


def test_srgb_decode_matches_formula():
    assert srgb_to_linear(np.array(0.5)) == pytest.approx(0.21404114, abs=1e-7)
    assert srgb_to_linear(np.array(0.04)) == pytest.approx(0.04 / 12.92)


def test_normals_from_height_match_closed_form():
    """z = a sin(2 pi u) sampled on texel centres: n ~ (-dz/du, -dz/dv, 1); v points up in the image."""
    h, w, a = 32, 64, 0.01
    j = torch.arange(w, dtype=torch.float64)
    i = torch.arange(h, dtype=torch.float64)
    u = (j + 0.5) / w
    v = 1 - (i + 0.5) / h
    height = torch.sin(2 * math.pi * u)[None, :] + torch.sin(2 * math.pi * v)[:, None]
    n = normals_from_height(height, a)
    # square texels of pitch 1/W texture widths: x = u, y = v * h / w (texture widths)
    dz_du = a * 2 * math.pi * torch.cos(2 * math.pi * u)[None, :].expand(h, w)
    dz_dy = a * 2 * math.pi * torch.cos(2 * math.pi * v)[:, None].expand(h, w) * (w / h)
    ref = torch.stack([-dz_du, -dz_dy, torch.ones_like(dz_du)], -1)
    ref = ref / ref.norm(dim=-1, keepdim=True)
    # central differences have relative error ~ (2 pi / n)^2 / 6
    torch.testing.assert_close(n, ref, atol=1.5e-3, rtol=0)


def test_missing_maps_raise(tmp_path):
    _write(tmp_path, "Wood_Color.png", np.zeros((4, 4, 3)))
    with pytest.raises(DataFormatError, match="missing roughness, normal or displacement"):
        load_texture_set(tmp_path)


def test_mismatched_sizes_raise(tmp_path):
    _synthetic_set(tmp_path, normal=False)
    _write(tmp_path, "Test_1K-JPG_Metalness.png", np.zeros((4, 4)))
    with pytest.raises(DataFormatError, match="different sizes.*Metalness.png 4x4"):
        load_texture_set(tmp_path)


def test_bad_arguments_raise(tmp_path):
    with pytest.raises(InputError, match="does not exist"):
        load_texture_set(tmp_path / "nope")
    _synthetic_set(tmp_path)
    with pytest.raises(InputError, match="height_scale"):
        load_texture_set(tmp_path, height_scale=-1)
    with pytest.raises(InputError, match="max_size"):
        load_texture_set(tmp_path, max_size=0)
    with pytest.raises(InputError, match="not inside"):
        load_texture_set(tmp_path).crop(4, 4, 8, 8)


def test_ambientcg_set_and_derived_normals_agree(shared_data):
    """Real data: normals derived from Wood092's displacement correlate with its NormalGL map (checks the
    orientation convention of both paths)."""
    ts = load_texture_set(shared_data / "svbrdf" / "Wood092_1K", max_size=256)
    assert ts.size == (256, 256) and not ts.normal_from_height
    assert 0 < ts.color.min() and ts.color.max() <= 1 and ts.metalness.abs().max() == 0
    derived = normals_from_height(ts.height, 0.002)
    for c in (0, 1):
        corr = torch.corrcoef(torch.stack([derived[..., c].flatten(), ts.normal[..., c].flatten()]))[0, 1]
        assert corr > 0.7


def test_cc0textures_partial_set(shared_data):
    ts = load_texture_set(shared_data / "svbrdf" / "Fabric02_1K_partial", max_size=64)
    assert ts.normal_from_height and ts.size == (64, 53)
    torch.testing.assert_close(ts.normal.norm(dim=-1), torch.ones(ts.size))
    crop = ts.crop(10, 5, 32, 16)
    assert crop.size == (32, 16) and torch.equal(crop.normal, ts.normal[10:42, 5:21])


def test_crop_keeps_full_resolution_texels(tmp_path):
    """crop=N is the top-left N x N of the full-resolution maps, texel for texel (no resampling), normals
    derived from height on the whole set."""
    folder = _synthetic_set(tmp_path, size=(8, 12), normal=False)
    full = load_texture_set(folder)
    ts = load_texture_set(folder, crop=5)
    assert ts.size == (5, 5)
    for name in ("color", "normal", "roughness", "metalness", "height"):
        assert torch.equal(getattr(ts, name), getattr(full, name)[:5, :5]), name
    assert not torch.equal(ts.color, load_texture_set(folder, max_size=5).color[:5, :5])
    with pytest.raises(InputError, match="crop"):
        load_texture_set(folder, crop=9)
    with pytest.raises(InputError, match="not both"):
        load_texture_set(folder, crop=4, max_size=4)


def test_crop_of_shared_set_matches_full_image(shared_data):
    folder = shared_data / "svbrdf" / "Wood092_1K"
    full, ts = load_texture_set(folder), load_texture_set(folder, crop=64)
    assert ts.size == (64, 64) and torch.equal(ts.roughness, full.roughness[:64, :64])
    assert torch.equal(ts.normal, full.normal[:64, :64])


def test_crop_origin_cuts_the_window_at_row_col(tmp_path):
    """crop=N with crop_origin=(row, col) is the N x N window starting there, texel for texel; a window past the
    edge, a bad origin or an origin without crop raise."""
    folder = _synthetic_set(tmp_path, size=(8, 12), normal=False)
    full = load_texture_set(folder)
    ts = load_texture_set(folder, crop=4, crop_origin=[3, 7])    # a list, as `--source-option crop_origin=3,7`
    for name in ("color", "normal", "roughness", "height"):
        assert torch.equal(getattr(ts, name), getattr(full, name)[3:7, 7:11]), name
    with pytest.raises(InputError, match="not inside"):
        load_texture_set(folder, crop=4, crop_origin=(5, 0))
    for bad in ({"crop_origin": (1, 1)}, {"crop": 4, "crop_origin": (1,)}, {"crop": 4, "crop_origin": (-1, 0)},
                {"crop": 4, "crop_origin": (1.5, 0)}):
        with pytest.raises(InputError, match="crop_origin"):
            load_texture_set(folder, **bad)
