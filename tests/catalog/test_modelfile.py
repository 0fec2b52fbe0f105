"""`.nmat` model files: bit-identical round trips of NeuBRDF in every mode, header contents, strict loading."""
from __future__ import annotations

import json

import pytest
import torch
from safetensors import safe_open
from safetensors.torch import save_file

from neumat.core.errors import DataFormatError, InputError
from neumat.core.query import Query
from neumat.fit.recipe import Recipe
from neumat.catalog.modelfile import load_model, save_model, source_info
from neumat.catalog.open_material import open_material
from neumat.io.modelfile import read_header
from neumat.methods.neubrdf.model import NeuBRDF


def _dirs(n: int, gen: torch.Generator) -> torch.Tensor:
    v = torch.randn(n, 3, generator=gen, dtype=torch.float64)
    v[:, 2] = v[:, 2].abs() + 1e-3
    return (v / v.norm(dim=-1, keepdim=True)).float()


def _trained_like(features: str, gen: torch.Generator) -> NeuBRDF:
    """A small NeuBRDF with non-trivial state: random logits / features, pruned grids."""
    torch.manual_seed(7)
    m = NeuBRDF(nside=4, index_bits=4, hidden=16, features=features)
    with torch.no_grad():
        for p in m.parameters():
            p.add_(torch.randn(p.shape, generator=gen) * 0.3)
    m.prune(_dirs(200, gen), _dirs(200, gen))
    return m


def _eval(m, q):
    with torch.no_grad():
        return m.eval(q)


@pytest.mark.parametrize("features", ["vq", "dense", "lowbit"])
@pytest.mark.parametrize("mode", ["train", "frozen", "runtime"])
def test_round_trip_is_bit_identical(features, mode, tmp_path, gen):
    m = _trained_like(features, gen)
    if mode == "frozen":
        m.freeze()
    if mode == "runtime":
        m.runtime()
    q = Query(_dirs(3000, gen), _dirs(3000, gen))
    ref = _eval(m, q)
    path = save_model(m, tmp_path / "m.nmat")
    loaded = load_model(path)
    assert type(loaded) is NeuBRDF and not loaded.training
    assert loaded.is_runtime == (mode == "runtime") and loaded.cfg == m.cfg
    assert torch.equal(_eval(loaded, q), ref)
    assert torch.equal(loaded.level_i, m.level_i) and torch.equal(loaded.level_o, m.level_o)
    assert loaded.size_bytes("fp16") == m.size_bytes("fp16")
    if mode != "train" and features != "dense":
        assert loaded.grid.frozen
    # and through the generic opener
    assert torch.equal(_eval(open_material(path), q), ref)


def test_header_contents(tmp_path, gen):
    m = _trained_like("vq", gen)
    recipe = Recipe(steps=10, batch_size=32, lr=0.01)
    (tmp_path / "src.binary").write_bytes(b"abc")
    path = save_model(m, tmp_path / "m.nmat", recipe=recipe, source=tmp_path / "src.binary",
                      metrics={"rmse_hdr": 0.5})
    h = read_header(path)
    assert h["type"] == "neubrdf" and h["format"] == "neumat-model" and h["format_version"] == 2
    assert h["config"]["nside"] == 4 and h["recipe"]["batch_size"] == 32 and h["metrics"] == {"rmse_hdr": 0.5}
    # sha256 of b"abc"
    assert h["source"] == {"name": "src.binary",
                           "sha256": "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"}
    assert h["size_bytes"]["fp16"] == m.size_bytes("fp16") and h["flops"] == m.flops()
    assert source_info("ggx:roughness=0.2")["name"] == "ggx:roughness=0.2"
    # a Material source is fingerprinted by its values: equal models hash equally, others not
    assert source_info(m)["sha256"] == source_info(load_model(path))["sha256"]
    assert source_info(m)["sha256"] != source_info(_trained_like("dense", gen))["sha256"]


def test_a_folder_source_is_hashed_by_its_files(tmp_path):
    """A texture set (a folder) is fingerprinted by its files' names and bytes: moved, the same source; a map
    edited in place, another one (a path hash kept fit-many's old fits and cached reference renderings of it)."""
    import shutil

    here = tmp_path / "a" / "Set"
    here.mkdir(parents=True)
    (here / "color.png").write_bytes(b"\x01\x02")
    (here / "sub").mkdir()
    (here / "sub" / "roughness.png").write_bytes(b"\x03")
    info = source_info(str(here))
    assert info["name"] == "Set" and len(info["sha256"]) == 64
    shutil.copytree(here, tmp_path / "b" / "Set")
    assert source_info(str(tmp_path / "b" / "Set"))["sha256"] == info["sha256"]
    (here / "sub" / "roughness.png").write_bytes(b"\x04")
    assert source_info(str(here))["sha256"] != info["sha256"]
    (here / "sub" / "roughness.png").rename(here / "roughness.png")  # same bytes, another name: another set
    assert source_info(str(here))["sha256"] not in (info["sha256"], source_info(str(tmp_path / "b" / "Set"))["sha256"])


def test_load_to_device_and_eval_mode(tmp_path, gen):
    m = _trained_like("dense", gen)
    loaded = load_model(save_model(m, tmp_path / "m.nmat"), device="cpu")
    assert next(loaded.parameters()).device.type == "cpu" and not loaded.training


def _rewrite(path, out, header_change=None, tensors_change=None, raw_header=None):
    """Copy a model file with an edited header / weights."""
    with safe_open(str(path), "pt") as f:
        meta = f.metadata()
        tensors = {k: f.get_tensor(k) for k in f.keys()}
    header = json.loads(meta["neumat"])
    if header_change:
        header_change(header)
    if tensors_change:
        tensors_change(tensors)
    save_file(tensors, str(out), metadata={"neumat": raw_header if raw_header is not None else json.dumps(header)})
    return out


def _set(key, value):
    return lambda h: h.__setitem__(key, value)


@pytest.mark.parametrize("edit, match", [
    (dict(header_change=_set("type", "neubrdff")), "unknown model 'neubrdff'.*did you mean neubrdf"),
    (dict(header_change=lambda h: h["config"].__setitem__("nsides", 4)), "unknown key.*nsides"),
    (dict(header_change=lambda h: h["config"].__setitem__("index_bits", 0)), "index_bits"),
    (dict(header_change=_set("format_version", 3)), "format version 3.*upgrade neumat"),
    (dict(header_change=_set("format", "other")), "format"),
    (dict(header_change=_set("colour", 1)), "unknown key.*colour"),
    (dict(header_change=lambda h: h.pop("config")), "lacks.*config"),
    (dict(tensors_change=lambda t: t.__setitem__("extra.weight", torch.zeros(2))), "Unexpected key.*extra"),
    (dict(tensors_change=lambda t: t.pop("mlp.net.0.bias")), "Missing key.*mlp.net.0.bias"),
    (dict(tensors_change=lambda t: t.__setitem__("mlp.net.0.bias", torch.zeros(3))), "size mismatch"),
    (dict(raw_header="{not json"), "not valid JSON"),
    (dict(header_change=lambda h: h["config"].__setitem__("hidden", 10 ** 30)), "bad config.*TypeError"),
])
def test_strict_loading_raises(edit, match, tmp_path, gen):
    path = save_model(_trained_like("dense", gen), tmp_path / "m.nmat")
    bad = _rewrite(path, tmp_path / "bad.nmat", **edit)
    with pytest.raises(DataFormatError, match=match):
        load_model(bad)


def test_model_files_of_the_renamed_zeltner_model_load_as_neumip_frame(tmp_path):
    """Files written when neumip-frame was registered as "zeltner" load as neumip-frame, with the same weights."""
    from neumat.methods.latent_mlp.neumip_frame import NeuMIPFrame

    m = NeuMIPFrame(spatial_size=8, spatial_channels=4, hidden=8, hidden_layers=1)
    old = _rewrite(save_model(m, tmp_path / "m.nmat"), tmp_path / "old.nmat", header_change=_set("type", "zeltner"))
    assert read_header(old)["type"] == "zeltner"
    loaded = load_model(old)
    assert isinstance(loaded, NeuMIPFrame) and loaded.name == "neumip-frame"
    for k, v in m.state_dict().items():
        assert torch.equal(loaded.state_dict()[k], v)


def test_truncated_garbage_and_foreign_files_raise(tmp_path, gen):
    path = save_model(_trained_like("vq", gen), tmp_path / "m.nmat")
    data = path.read_bytes()
    for cut in (len(data) - 10, len(data) // 2, 20, 3):
        (tmp_path / "cut.nmat").write_bytes(data[:cut])
        with pytest.raises(DataFormatError, match="truncated"):
            load_model(tmp_path / "cut.nmat")
    (tmp_path / "junk.nmat").write_bytes(b"\x00" * 64)
    with pytest.raises(DataFormatError, match="cut.nmat|junk.nmat"):
        load_model(tmp_path / "junk.nmat")
    save_file({"a": torch.zeros(2)}, str(tmp_path / "foreign.nmat"))
    with pytest.raises(DataFormatError, match="no neumat header"):
        load_model(tmp_path / "foreign.nmat")
    with pytest.raises(InputError, match="does not exist"):
        load_model(tmp_path / "missing.nmat")


def test_other_neumat_version_warns(tmp_path, gen):
    path = save_model(_trained_like("dense", gen), tmp_path / "m.nmat")
    old = _rewrite(path, tmp_path / "old.nmat", header_change=_set("neumat_version", "0.0.1"))
    with pytest.warns(UserWarning, match="written by neumat 0.0.1"):
        load_model(old)


def test_bad_save_arguments_raise(tmp_path, gen):
    m = _trained_like("dense", gen)
    with pytest.raises(InputError, match=".nmat"):
        save_model(m, tmp_path / "m.pt")
    with pytest.raises(InputError, match="JSON"):
        save_model(m, tmp_path / "m.nmat", metrics={"rmse": float("nan")})
    with pytest.raises(InputError, match="registered neumat model"):
        save_model(torch.nn.Linear(2, 2), tmp_path / "m.nmat")
    assert not (tmp_path / "m.nmat").exists()
