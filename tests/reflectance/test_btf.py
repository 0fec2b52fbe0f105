"""Tabulated BTF material, direction sets and the .nbtf file format."""
from __future__ import annotations


import pytest
import torch

from neumat import DataFormatError, InputError, Query
from neumat.io.btf import read_btf_header, write_btf
from neumat.reflectance.btf import TabulatedBTF, angular_weights, direction_set, read_btf


def _uv_of(rows, cols, h, w):
    return torch.stack([(cols + 0.5) / w, 1 - (rows + 0.5) / h], -1)


@pytest.fixture
def small_btf(gen) -> TabulatedBTF:
    d = direction_set("rings:3x30")
    data = torch.rand(d.shape[0], d.shape[0], 6, 8, 3, generator=gen)
    return TabulatedBTF(data, d, d)


def test_direction_sets_are_unit_upper_hemisphere():
    for spec, n in (("hemi151", 151), ("ubo151", 151), ("ubo81", 81), ("rings:3x30", 17), (25, 25)):
        d = direction_set(spec)
        assert d.shape == (n, 3)
        assert torch.allclose(d.norm(dim=-1), torch.ones(n), atol=1e-6)
        assert bool((d[:, 2] > 0).all())
    with pytest.raises(InputError, match="direction set"):
        direction_set("rings:9x15")
    for spec in ("rings:3xnan", "rings:1xnan", "rings:2x-inf", "rings:3x0"):
        with pytest.raises(InputError, match="ring step must be a positive number"):
            direction_set(spec)


def test_ubo151_ring_angles_and_azimuth_offsets():
    d = direction_set("ubo151").double()
    theta = torch.rad2deg(torch.acos(d[:, 2].clamp(max=1)))
    phi = torch.rad2deg(torch.atan2(d[:, 1], d[:, 0])) % 360
    for theta_deg, count, offset in ((11.0, 6, 15.0), (52.5, 18, 7.5), (75.0, 24, 0.0)):
        ring = (theta - theta_deg).abs() < 1e-4
        assert int(ring.sum()) == count
        assert torch.allclose(phi[ring].sort().values, (offset + 360.0 / count * torch.arange(count)).double(),
                              atol=1e-4)


def test_lookup_at_bins_and_texel_centres_is_exact(small_btf):
    b = small_btf
    l, v, h, w, _ = b.data.shape
    li = torch.tensor([0, 3, 16, 7])
    vi = torch.tensor([5, 0, 9, 16])
    rows, cols = torch.tensor([0, 5, 2, 3]), torch.tensor([7, 0, 4, 1])
    q = Query(b.light_dirs[li], b.view_dirs[vi], uv=_uv_of(rows.float(), cols.float(), h, w))
    assert torch.allclose(b.eval(q), b.data[li, vi, rows, cols], atol=1e-6)


def test_spatial_bilinear_wraps_around(small_btf):
    b = small_btf
    h, w = b.data.shape[2:4]
    # uv exactly between the last and the first column (wrap-around): the mean of both texels
    q = Query(b.light_dirs[:1], b.view_dirs[:1], uv=torch.tensor([[0.0, 1 - 0.5 / h]]))
    expect = (b.data[0, 0, 0, 0] + b.data[0, 0, 0, w - 1]) / 2
    assert torch.allclose(b.eval(q)[0], expect, atol=1e-6)


def test_angular_weights_are_inverse_distance():
    d = direction_set("rings:3x30")
    w = torch.nn.functional.normalize(d[0] + d[1], dim=0)[None]  # halfway between bins 0 and 1
    idx, wt = angular_weights(d, w, k=2)
    assert set(idx[0].tolist()) == {0, 1}
    assert torch.allclose(wt, torch.full((1, 2), 0.5), atol=1e-5)
    ang = torch.acos((w @ d.T).clamp(-1, 1))[0]
    idx3, wt3 = angular_weights(d, w, k=3)
    inv = 1 / ang[idx3[0]]
    assert torch.allclose(wt3[0], inv / inv.sum(), atol=1e-5)


def test_below_horizon_is_zero(small_btf):
    q = Query(torch.tensor([[0.0, 0.6, -0.8]]), torch.tensor([[0.0, 0.0, 1.0]]), uv=torch.tensor([[0.3, 0.3]]))
    assert torch.equal(small_btf.eval(q), torch.zeros(1, 3))


def test_inconsistent_direction_counts_raise(small_btf):
    with pytest.raises(InputError, match="light directions"):
        TabulatedBTF(small_btf.data, small_btf.light_dirs[:5], small_btf.view_dirs)
    with pytest.raises(InputError, match="upper hemisphere"):
        TabulatedBTF(small_btf.data[:1, :1], -small_btf.light_dirs[:1], small_btf.view_dirs[:1])


def test_file_round_trip_fp16(tmp_path, small_btf):
    path = write_btf(tmp_path / "a.nbtf", small_btf)
    head = read_btf_header(path)
    assert (head["n_light"], head["n_view"], head["height"], head["width"]) == (17, 17, 6, 8)
    back = read_btf(path)
    assert torch.allclose(back.data, small_btf.data, atol=1e-3)  # float16 storage
    part = read_btf(path, lights=[2, 4])
    assert torch.equal(part.data, back.data[[2, 4]])
    exact = read_btf(write_btf(tmp_path / "b.nbtf", small_btf, dtype="float32"))
    assert torch.equal(exact.data, small_btf.data)


def test_truncated_and_inconsistent_files_raise(tmp_path, small_btf):
    path = write_btf(tmp_path / "a.nbtf", small_btf)
    raw = path.read_bytes()
    cut = tmp_path / "cut.nbtf"
    cut.write_bytes(raw[: len(raw) // 2])
    with pytest.raises(DataFormatError, match="cut.nbtf"):
        read_btf(cut)
    # a header claiming more light directions than the file holds
    from safetensors.torch import load_file, save_file
    import json
    tensors = load_file(str(path))
    from safetensors import safe_open
    with safe_open(str(path), framework="pt") as f:
        head = json.loads(f.metadata()["neumat_btf"])
    head["n_light"] = 18
    bad = tmp_path / "bad.nbtf"
    save_file(tensors, str(bad), metadata={"neumat_btf": json.dumps(head)})
    with pytest.raises(DataFormatError, match="18 light directions but the file has 17"):
        read_btf(bad)
    # direction list shorter than the chunks
    tensors["view_dirs"] = tensors["view_dirs"][:5]
    head["n_light"] = 17
    save_file(tensors, str(bad), metadata={"neumat_btf": json.dumps(head)})
    with pytest.raises(DataFormatError, match="direction"):
        read_btf(bad)
    with pytest.raises(InputError, match="does not exist"):
        read_btf(tmp_path / "missing.nbtf")


def _with_header(src, dst, key: str, **fields):
    """Copy safetensors file `src` to `dst` with fields of its JSON header (metadata `key`) replaced."""
    import json

    from safetensors import safe_open
    from safetensors.torch import save_file
    with safe_open(str(src), framework="pt") as f:
        meta, tensors = dict(f.metadata()), {k: f.get_tensor(k) for k in f.keys()}
    meta[key] = json.dumps({**json.loads(meta[key]), **fields})
    save_file(tensors, str(dst), metadata=meta)
    return dst


@pytest.mark.parametrize("field,value", [("label", [1]), ("extra", "x"), ("clamped", 1.5), ("version", True),
                                         ("n_view", "17"), ("n_light", 10 ** 30)])
def test_header_fields_of_the_wrong_json_type_are_data_format_errors(tmp_path, small_btf, field, value):
    """Each a one-line error at the CLI, exit 2 (n_light 1e30 used to exhaust the memory building names)."""
    from typer.testing import CliRunner

    from neumat.cli.main import app
    bad = _with_header(write_btf(tmp_path / "a.nbtf", small_btf), tmp_path / "bad.nbtf", "neumat_btf",
                       **{field: value})
    with pytest.raises(DataFormatError, match=field if field != "n_light" else "light chunks"):
        read_btf(bad)
    r = CliRunner().invoke(app, ["data", "info", str(bad)])
    assert r.exit_code == 2 and r.output.startswith("error: ") and len(r.output.strip().splitlines()) == 1, r.output


@pytest.mark.parametrize("field,value", [("patch", "8"), ("tau_train", 4), ("log_eps", None), ("info", [1])])
def test_dictionary_header_fields_of_the_wrong_json_type_are_data_format_errors(tmp_path, field, value):
    from neumat.methods.sparse_btf.dictionary import BTFDictionary, shipped_dictionary
    bad = _with_header(shipped_dictionary("default"), tmp_path / "bad.nmat", "neumat", **{field: value})
    with pytest.raises(DataFormatError, match=f"header field '{field}' must be"):
        BTFDictionary.load(bad)
