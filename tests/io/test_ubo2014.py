"""Bonn `.btf` (UBO2014 DFMF, FMF) reader against small files written here in the documented byte layout."""
from __future__ import annotations

import math
import struct

import numpy as np
import pytest
import torch

from neumat.core.errors import DataFormatError, InputError
from neumat.catalog.open_material import open_material
from neumat.io.ubo2014 import read_ubo2014_header
from neumat.reflectance.btf import read_ubo2014
from neumat.reflectance.btf import TabulatedBTF

H, W = 4, 3                     # texture height (rows) and width (columns)
EPS = 1e-5
YUV_TO_RGB = np.array([[1, 0, 1.13983], [1, -0.39465, -0.5806], [1, 2.03211, 0]])
# five light and five view directions (theta, phi) in degrees, taken from UBO Dome 1 rings
LIGHTS_DEG = [(0, 0), (11, 15), (30, 90), (45, 180), (75, -90)]
VIEWS_DEG = [(0, 0), (23.5, 0), (37.5, 120), (60, -60), (67.5, 7.5)]


# ---------------------------------------------------------------- a writer following the documented layout
def meta_block(version=4, cosine_flag=0, xml=b"<btf/>", channels=(b"R", b"G", b"B"), size_delta=0) -> bytes:
    body = struct.pack("<I", version) + b"UBO dome 1".ljust(80, b"\0") + b"sensor".ljust(80, b"\0")
    body += b"LEDs".ljust(80, b"\0") + struct.pack("<f3f", 10.0, 1.0, 1.0, 1.0)
    if version > 1:
        body += struct.pack("<I", cosine_flag)
    if version > 2:
        body += struct.pack("<I", len(xml)) + xml
    if version > 3:
        body += struct.pack("<I", len(channels)) + b"".join(struct.pack("<I", len(c)) + c for c in channels)
    return struct.pack("<I", len(body) + 4 + size_delta) + body


def sampling_block(lights_deg=LIGHTS_DEG, views_deg=VIEWS_DEG, light_counts=None) -> bytes:
    lights = np.radians(np.asarray(lights_deg, np.float64)).astype("<f4")
    out = struct.pack("<I", len(views_deg))
    for i, v in enumerate(views_deg):
        n = len(lights) if light_counts is None else light_counts[i]
        out += np.radians(np.asarray(v, np.float64)).astype("<f4").tobytes() + struct.pack("<I", n)
        out += lights[:n].tobytes()
    return out


def common_header(signature: bytes, n_rotations=1, **meta) -> bytes:
    out = signature + meta_block(**meta) + sampling_block() + struct.pack("<II", W, H)
    if signature.endswith(b"R"):
        out += struct.pack("<I", n_rotations) + np.eye(3, dtype="<f4").tobytes() * n_rotations
    return out


def factor_bytes(u: np.ndarray, sxv: np.ndarray, dtype: str) -> bytes:
    """Singular values (column norms of SxV), then U and SxV row-major."""
    s = np.linalg.norm(sxv, axis=0)
    return s.astype(dtype).tobytes() + u.astype(dtype).tobytes() + sxv.astype(dtype).tobytes()


def dfmf_file(path, us, sxvs, color_model=0, mean=(0, 0, 0), matrix=None, dtype="<f4", **meta):
    """us[c] (rows x P_c) and sxvs[c] (cols x P_c) per decorrelated channel."""
    size = {"<f2": 2, "<f4": 4, "<f8": 8}[dtype]
    out = common_header(b"!DFMF08FCR", **meta)
    matrix = np.eye(3) if matrix is None else matrix
    out += struct.pack("<Ii3f9f", max(u.shape[1] for u in us), color_model, *mean, *np.ravel(matrix))
    for u, sxv in zip(us, sxvs):
        out += struct.pack("<BIII", size, u.shape[1], u.shape[0], sxv.shape[0]) + factor_bytes(u, sxv, dtype)
    path.write_bytes(out)
    return path


def fmf_file(path, u, sxv, drr=0, height_map=(2, 2)):
    out = common_header(b"!FMF12FCER") + struct.pack("<BI", 2, drr) + struct.pack("<II", *height_map)
    out += np.zeros(height_map, "<f2").tobytes()
    p = u.shape[1]
    out += struct.pack("<IBIII", p, 4, p, u.shape[0], sxv.shape[0]) + factor_bytes(u, sxv, "<f4")
    path.write_bytes(out)
    return path


# ---------------------------------------------------------------- known tables
def stored_table(table: np.ndarray) -> np.ndarray:
    """Our (L, V, H, W, C) table as the file's (n_view * n_light, H * W, C) matrix: lv = v * L + l,
    xy = y * W + x with stored row y = H - 1 - our row."""
    flipped = table[:, :, ::-1]
    l, v = flipped.shape[:2]
    return flipped.transpose(1, 0, 2, 3, 4).reshape(v * l, H * W, -1)


def exact_factors(m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """U and SxV of the full SVD of m (rows x cols)."""
    u, s, vt = np.linalg.svd(m, full_matrices=False)
    return u, vt.T * s


def rgb_table(seed=0) -> np.ndarray:
    """A positive (5, 5, H, W, 3) apparent-BRDF table."""
    return np.random.default_rng(seed).uniform(0.05, 2.0, (5, 5, H, W, 3))


def encode(rgb: np.ndarray, model: int, mean: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    """Forward colour transform (..., 3): the inverse of what the reader must undo."""
    if model == 0:
        return rgb
    if model == 1:
        return rgb @ np.linalg.inv(YUV_TO_RGB).T
    if model == 3:
        return (rgb - mean) @ np.linalg.inv(matrix)
    if model == 4:
        return rgb @ np.linalg.inv(np.array([[1, 1, -1], [1, 0, 1], [1, -1, -1]])).T
    if model == 11:
        yuv = rgb @ np.linalg.inv(YUV_TO_RGB).T
        y = yuv[..., :1]
        return np.concatenate([np.log(y + EPS), yuv[..., 1:] / (y + EPS)], -1)
    if model == 12:
        return np.log(rgb + EPS)
    raise AssertionError(model)


# ---------------------------------------------------------------- tests
def test_rank2_table_is_reconstructed(tmp_path):
    g = np.random.default_rng(1)
    us = [g.normal(size=(25, 2)) for _ in range(3)]
    sxvs = [g.normal(size=(H * W, 2)) for _ in range(3)]
    btf = read_ubo2014(dfmf_file(tmp_path / "rank2.btf", us, sxvs))
    assert isinstance(btf, TabulatedBTF) and btf.shape == (5, 5, H, W)
    for c in range(3):
        full = us[c] @ sxvs[c].T                                   # (lv, xy)
        for l, v, i, j in [(0, 0, 0, 0), (2, 3, 1, 2), (4, 1, 3, 0), (1, 4, 2, 1)]:
            expected = full[v * 5 + l, (H - 1 - i) * W + j]
            assert btf.data[l, v, i, j, c].item() == pytest.approx(expected, abs=2e-6)
    expected = np.stack([u @ s.T for u, s in zip(us, sxvs)], -1).reshape(5, 5, H, W, 3)  # (v, l, y, x, c)
    expected = expected.transpose(1, 0, 2, 3, 4)[:, :, ::-1]
    np.testing.assert_allclose(btf.data.numpy(), expected, atol=2e-6)


def test_float16_factors(tmp_path):
    g = np.random.default_rng(2)
    us = [g.normal(size=(25, 2)) for _ in range(3)]
    sxvs = [g.normal(size=(H * W, 2)) for _ in range(3)]
    btf = read_ubo2014(dfmf_file(tmp_path / "half.btf", us, sxvs, dtype="<f2"))
    half = [u.astype(np.float16).astype(np.float64) @ s.astype(np.float16).astype(np.float64).T
            for u, s in zip(us, sxvs)]
    expected = np.stack(half, -1).reshape(5, 5, H, W, 3).transpose(1, 0, 2, 3, 4)[:, :, ::-1]
    np.testing.assert_allclose(btf.data.numpy(), expected, atol=1e-5)
    assert read_ubo2014_header(tmp_path / "half.btf").scalar_size == 2


@pytest.mark.parametrize("model", [0, 1, 3, 4, 11, 12])
def test_colour_models_give_back_linear_rgb(tmp_path, model):
    rgb = rgb_table(model)
    q, _ = np.linalg.qr(np.random.default_rng(3).normal(size=(3, 3)))
    mean = np.array([0.3, 0.2, 0.1])
    decorrelated = stored_table(encode(rgb, model, mean, q))
    factors = [exact_factors(decorrelated[..., c]) for c in range(3)]
    path = dfmf_file(tmp_path / f"model{model}.btf", [f[0] for f in factors], [f[1] for f in factors],
                     color_model=model, mean=mean, matrix=q, dtype="<f8")
    btf = read_ubo2014(path)
    np.testing.assert_allclose(btf.data.numpy(), rgb, rtol=1e-5, atol=1e-6)


def test_spatial_u_orientation(tmp_path):
    rgb = rgb_table(4)
    decorrelated = stored_table(rgb)
    factors = [exact_factors(decorrelated[..., c].T) for c in range(3)]     # U spatial (H W rows)
    btf = read_ubo2014(dfmf_file(tmp_path / "t.btf", [f[0] for f in factors], [f[1] for f in factors]))
    np.testing.assert_allclose(btf.data.numpy(), rgb, rtol=1e-4, atol=1e-5)


def test_fmf_with_dynamic_range_reduction(tmp_path):
    rgb = rgb_table(5)
    logged = stored_table(np.log(rgb + EPS))                               # (lv, xy, c)
    by_rows = logged.transpose(0, 2, 1).reshape(25 * 3, H * W)              # row = lv * 3 + c
    u, sxv = exact_factors(by_rows)
    btf = read_ubo2014(fmf_file(tmp_path / "f.btf", u, sxv, drr=1))
    np.testing.assert_allclose(btf.data.numpy(), rgb, rtol=1e-4)
    header = read_ubo2014_header(tmp_path / "f.btf")
    assert header.variant == "FMF" and header.dynamic_range_reduction and header.components == (12, 12, 12)


def test_cosine_flag_divides_by_cos_theta_light(tmp_path):
    rgb = rgb_table(6)
    cos_l = np.cos(np.radians([t for t, _ in LIGHTS_DEG]))
    stored = stored_table(rgb * cos_l[:, None, None, None, None])
    factors = [exact_factors(stored[..., c]) for c in range(3)]
    btf = read_ubo2014(dfmf_file(tmp_path / "cos.btf", [f[0] for f in factors], [f[1] for f in factors],
                                 cosine_flag=1))
    np.testing.assert_allclose(btf.data.numpy(), rgb, rtol=1e-4)


def test_directions_follow_theta_phi(tmp_path):
    g = np.random.default_rng(7)
    path = dfmf_file(tmp_path / "d.btf", [g.normal(size=(25, 1))] * 3, [g.normal(size=(H * W, 1))] * 3)
    btf = read_ubo2014(path)
    s30, c30 = math.sin(math.radians(30)), math.cos(math.radians(30))
    torch.testing.assert_close(btf.light_dirs[2], torch.tensor([0.0, s30, c30]), atol=1e-6, rtol=0)
    torch.testing.assert_close(btf.light_dirs[0], torch.tensor([0.0, 0.0, 1.0]), atol=1e-7, rtol=0)
    t, p = math.radians(60), math.radians(-60)
    torch.testing.assert_close(btf.view_dirs[3], torch.tensor([math.sin(t) * math.cos(p), math.sin(t) * math.sin(p),
                                                               math.cos(t)]), atol=1e-6, rtol=0)
    header = read_ubo2014_header(path)
    assert header.channel_names == ("R", "G", "B") and header.xml == "<btf/>"
    assert header.measurement_setup == "UBO dome 1"


def test_crop_step_and_truncation(tmp_path):
    g = np.random.default_rng(8)
    us = [g.normal(size=(25, 3)) for _ in range(3)]
    sxvs = [g.normal(size=(H * W, 3)) for _ in range(3)]
    path = dfmf_file(tmp_path / "c.btf", us, sxvs)
    full = read_ubo2014(path).data
    crop = read_ubo2014(path, texels=(1, 1, 3, 2))
    assert crop.shape == (5, 5, 3, 2)
    torch.testing.assert_close(crop.data, full[:, :, 1:4, 1:3])
    decimated = read_ubo2014(path, step=2)
    torch.testing.assert_close(decimated.data, full[:, :, ::2, ::2])
    rank1 = read_ubo2014(path, max_components=1).data
    expected = np.stack([u[:, :1] @ s[:, :1].T for u, s in zip(us, sxvs)], -1)
    expected = expected.reshape(5, 5, H, W, 3).transpose(1, 0, 2, 3, 4)[:, :, ::-1]
    np.testing.assert_allclose(rank1.numpy(), expected, atol=2e-6)


def test_open_material_reads_btf_suffix(tmp_path):
    g = np.random.default_rng(9)
    path = dfmf_file(tmp_path / "m.btf", [g.normal(size=(25, 1))] * 3, [g.normal(size=(H * W, 1))] * 3)
    mat = open_material(path, texels=(0, 0, 2, 2))
    assert isinstance(mat, TabulatedBTF) and mat.shape == (5, 5, 2, 2)


def good_file(tmp_path, **kw):
    g = np.random.default_rng(10)
    return dfmf_file(tmp_path / "good.btf", [g.normal(size=(25, 2))] * 3, [g.normal(size=(H * W, 2))] * 3, **kw)


@pytest.mark.parametrize("cut", [5, 40, 400, -200, -1])
def test_truncated_file(tmp_path, cut):
    data = good_file(tmp_path).read_bytes()
    bad = tmp_path / "cut.btf"
    bad.write_bytes(data[:cut])
    with pytest.raises(DataFormatError, match="cut.btf"):
        read_ubo2014(bad)


@pytest.mark.parametrize("start, message", [(b"!XYZ0000000", "unknown signature"), (b"!PVF06FCR", "PVF"),
                                            (b"!BDIF06R2!", "BDI")])
def test_wrong_or_unsupported_signature(tmp_path, start, message):
    data = good_file(tmp_path).read_bytes()
    bad = tmp_path / "sig.btf"
    bad.write_bytes(start + data[10:])
    with pytest.raises(DataFormatError, match=message):
        read_ubo2014(bad)


def test_inconsistent_files(tmp_path):
    data = good_file(tmp_path).read_bytes()
    trailing = tmp_path / "trailing.btf"
    trailing.write_bytes(data + b"\0\0")
    with pytest.raises(DataFormatError, match="trailing"):
        read_ubo2014(trailing)
    g = np.random.default_rng(11)
    with pytest.raises(DataFormatError, match="direction pairs"):     # U rows match neither layout
        read_ubo2014(dfmf_file(tmp_path / "rows.btf", [g.normal(size=(24, 1))] * 3, [g.normal(size=(H * W, 1))] * 3))
    with pytest.raises(DataFormatError, match="meta data block"):
        read_ubo2014(good_file(tmp_path, size_delta=4))
    with pytest.raises(DataFormatError, match="colour model 2"):
        read_ubo2014(good_file(tmp_path, color_model=2))
    with pytest.raises(DataFormatError, match="channels"):
        read_ubo2014(good_file(tmp_path, channels=(b"L",)))
    views = tmp_path / "views.btf"
    head = common_header(b"!DFMF08FCR")
    changed = head.replace(sampling_block(), sampling_block(light_counts=[5, 4, 5, 5, 5]))
    views.write_bytes(changed + data[len(head):])
    with pytest.raises(DataFormatError, match="view-dependent"):
        read_ubo2014(views)


def test_bad_arguments(tmp_path):
    path = good_file(tmp_path)
    for kw in ({"texels": (0, 0, H + 1, 1)}, {"texels": (0, 0, 1)}, {"step": 0}, {"max_components": 0}):
        with pytest.raises(InputError):
            read_ubo2014(path, **kw)
    with pytest.raises(InputError, match="GiB"):
        read_ubo2014(path, max_gib=1e-9)
    with pytest.raises(InputError, match="does not exist"):
        read_ubo2014(tmp_path / "missing.btf")
