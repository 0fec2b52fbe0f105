"""`neumat translucent trace | fit | render` end to end on a tiny budget, and their errors."""
from __future__ import annotations

import pytest
import torch
from typer.testing import CliRunner

from neumat.cli.main import app
from neumat.fit.translucent_observations import Observations
from neumat.io.images import read_image
from neumat.catalog.modelfile import load_model
from neumat.io.modelfile import read_header
from neumat.methods.neupress.model import NeuPreSS
from tests.mitsuba_util import mitsuba_or_skip


def _run(*args):
    return CliRunner().invoke(app, ["translucent", *map(str, args)])


def _said(result) -> str:
    """The command's output with rich's line wrapping undone."""
    return "".join(result.output.split())


@pytest.mark.mitsuba
def test_trace_fit_render(tmp_path):
    mitsuba_or_skip()
    obs, model, image, picture = (tmp_path / n for n in ("o.npz", "m.nmat", "img.exr", "cmp.png"))
    r = _run("trace", "-o", obs, "--images", 4, "--resolution", 8, "--spp", 2, "--media", "marble,skin1")
    assert r.exit_code == 0, r.output
    data = Observations.load(obs)
    assert len(data) > 0 and Observations.load_source(obs)["object"]["media"] == ["marble", "skin1"]

    # 22 steps: 20 of the appearance module, 2 of the sampler
    r = _run("fit", obs, "-o", model, "--steps", 22, "--set", "batch_size=64", "--set", "phase_split=[0.9,0.1]",
             "--validation", 0.25, "--device", "cpu", "--checkpoint", tmp_path / "fit.ckpt")
    assert r.exit_code == 0, r.output
    m = load_model(model)
    assert isinstance(m, NeuPreSS) and m.cfg.feature_std == 0.3
    metrics = read_header(model)["metrics"]
    assert 1 <= metrics["best_step"] <= 20 and metrics["validation_mse"] > 0
    box = Observations.load_source(obs)["bbox"]  # the object's bounding box, written by trace
    assert torch.allclose(m.box_min, torch.tensor(box[0])) and torch.allclose(m.box_max, torch.tensor(box[1]))

    r = _run("render", model, obs, "-o", image, "--resolution", 8, "--spp", 2, "--env-width", 16)
    assert r.exit_code == 0, r.output
    img = read_image(image)  # full appearance by default: the corners show the environment
    assert img.shape == (8, 8, 3) and float(img.min()) >= 0 and float(img[0, 0].min()) > 0
    r = _run("render", model, obs, "-o", image, "--resolution", 8, "--spp", 2, "--env-width", 16,
             "--appearance", "subsurface", "--strategy", "light")
    assert r.exit_code == 0, r.output
    img = read_image(image)
    assert float(img.max()) > 0 and float(img[0, 0].max()) == 0  # the learned term alone, on black

    r = _run("render", model, obs, "-o", picture, "--resolution", 8, "--spp", 2, "--env-width", 16,
             "--strategy", "model", "--reference-spp", 2)
    assert r.exit_code == 0, r.output
    said = _said(r)
    # two rows: the model, and a second reference against the first (the noise floor); FLIP also on the object
    assert "noisefloor" in said and "FLIP,object" in said and "reference,another" in said, r.output
    assert read_image(picture).ndim == 3

    r = _run("render", model, obs, "-o", image, "--strategy", "bsdf")
    assert r.exit_code == 2 and "light|model|mis" in _said(r)
    r = _run("render", model, obs, "-o", image, "--appearance", "surface")
    assert r.exit_code == 2 and "full|subsurface" in _said(r)

    r = _run("render", model, obs, "-o", tmp_path / "x.exr", "--reference-spp", 2)
    assert r.exit_code == 2 and ".png" in _said(r)


def test_errors_name_the_problem(tmp_path, without_llvm):
    """Without a usable LLVM too: each argument is checked before Mitsuba loads."""
    r = _run("trace", "-o", tmp_path / "o.txt")
    assert r.exit_code == 2 and ".npz" in _said(r)
    r = _run("trace", "-o", tmp_path / "o.npz", "--scene", "cone")
    assert r.exit_code == 2 and "mesh:PATH" in _said(r)
    r = _run("fit", tmp_path / "missing.npz", "-o", tmp_path / "m.nmat")
    assert r.exit_code == 2 and "doesnotexist" in _said(r)
    x = torch.tensor([[0.0, 0.0, 1.0]]).repeat(4, 1)  # unit vectors: Observations refuses others
    Observations(x, x, x, x, x).save(tmp_path / "plain.npz")
    r = _run("fit", tmp_path / "plain.npz", "-o", tmp_path / "m.pt")
    assert r.exit_code == 2 and ".nmat" in _said(r)
    from neumat.catalog.modelfile import save_model
    from neumat.models.registry import build_model
    other = save_model(build_model({"type": "naive-mlp"}), tmp_path / "other.nmat")
    r = _run("render", other, tmp_path / "plain.npz", "-o", tmp_path / "i.png")
    assert r.exit_code == 2 and "NeuPreSS" in _said(r)
    save_model(NeuPreSS(features=4, width=4, layers=1, sampler_hidden=(4,)), tmp_path / "n.nmat")
    r = _run("render", tmp_path / "n.nmat", tmp_path / "plain.npz", "-o", tmp_path / "i.png")
    assert r.exit_code == 2 and "objectdescription" in _said(r)
    r = _run("render", tmp_path / "n.nmat", tmp_path / "plain.npz", "-o", tmp_path / "i.png", "--light", "point:0/0/1")
    assert r.exit_code == 2 and "env:sky" in _said(r)
    from neumat.core.config import config_to_dict
    from neumat.reflectance.translucent import TranslucentConfig
    Observations(x, x, x, x, x).save(tmp_path / "o.npz", source={"object": config_to_dict(TranslucentConfig())})
    for option, value, message in (("--strategy", "bsdf", "light|model|mis"), ("--appearance", "surface",
                                   "full|subsurface"), ("--reference-spp", 2, ".png")):
        r = _run("render", tmp_path / "n.nmat", tmp_path / "o.npz", "-o", tmp_path / "i.exr", option, value)
        assert r.exit_code == 2 and message in _said(r), r.output
    r = _run("trace", "-o", tmp_path / "t.npz", "--roughness-texture", tmp_path / "none.exr")
    assert r.exit_code == 2 and "none.exr" in _said(r), r.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["n.nmat", "o.npz", "other.nmat", "plain.npz"]


def test_fit_takes_recipe_and_config_overrides_and_resumes(tmp_path):
    """No Mitsuba: synthetic observations; --set reaches the model config, the recipe and its options; a second
    run with --resume continues from the finished checkpoint to the same model."""
    g = torch.Generator().manual_seed(0)
    x = torch.nn.functional.normalize(torch.randn(200, 3, generator=g), dim=-1)
    wi = torch.nn.functional.normalize(torch.randn(200, 3, generator=g), dim=-1)
    Observations(x, x.clone(), x.clone(), wi, torch.rand(200, 3, generator=g)).save(tmp_path / "o.npz")
    args = ["fit", tmp_path / "o.npz", "--steps", 6, "--device", "cpu", "-q", "--checkpoint", tmp_path / "f.ckpt",
            "--set", "features=8", "--set", "width=8", "--set", "layers=1", "--set", "sampler_hidden=[4]",
            "--set", "batch_size=16", "--set", "log_every=2", "--set", "sampler_batch=2", "--set", "grid=[4,8]"]
    r = _run(*args, "-o", tmp_path / "a.nmat")
    assert r.exit_code == 0, r.output
    a, header = load_model(tmp_path / "a.nmat"), read_header(tmp_path / "a.nmat")
    assert a.cfg.features == 8 and a.cfg.feature_std == 0.3 and header["recipe"]["batch_size"] == 16
    assert header["recipe"]["options"]["grid"] == [4, 8] and header["metrics"]["best_step"] in (2, 4, 5)
    r = _run(*args, "--resume", "-o", tmp_path / "b.nmat")
    assert r.exit_code == 0, r.output
    b = load_model(tmp_path / "b.nmat")
    assert all(torch.equal(a.state_dict()[k], v) for k, v in b.state_dict().items())
    r = _run(*args[:-2], "--set", "batch=16", "-o", tmp_path / "c.nmat")
    assert r.exit_code == 2 and "batch_size" in _said(r)
    r = _run("fit", tmp_path / "o.npz", "-o", tmp_path / "c.nmat", "--batch", 16)
    assert r.exit_code == 2


@pytest.mark.mitsuba
def test_trace_scene_options_and_noise_floor(tmp_path):
    """--max-depth, --inner (a .json file), the textures, --roughness-range and --sampler reach the saved object
    config (with the default interior_emitter_sampling, false); the
    noise estimate is printed and saved, and --noise-check 0 skips it."""
    mitsuba_or_skip()
    import json

    import numpy as np

    from neumat.io.images import write_image
    write_image(tmp_path / "r.exr", np.full((4, 8, 3), 0.5, np.float32))
    (tmp_path / "inner.json").write_text(json.dumps([{"medium": "skin1", "scale": 0.4, "ior": 1.4}]))
    r = _run("trace", "-o", tmp_path / "o.npz", "--images", 3, "--resolution", 8, "--spp", 4, "-q",
             "--sampler", "orthogonal",
             "--max-depth", 100, "--inner", tmp_path / "inner.json", "--roughness-texture", tmp_path / "r.exr",
             "--roughness-range", "0.1,0.2", "--albedo-texture", tmp_path / "r.exr", "--noise-check", 16)
    assert r.exit_code == 0, r.output
    source = Observations.load_source(tmp_path / "o.npz")
    cfg = source["object"]
    assert cfg["max_depth"] == 100 and cfg["inner"][0]["medium"] == "skin1" and cfg["roughness_range"] == [0.1, 0.2]
    assert cfg["roughness_texture"] == cfg["albedo_texture"] == str(tmp_path / "r.exr")
    assert cfg["sampler"] == "orthogonal" and cfg["interior_emitter_sampling"] is False
    noise = source["noise"]
    assert 0 < noise["observations"] <= 16 and noise["variance"] > 0 and noise["relative"] > 0
    assert "noisefloor" in _said(r) and "CPUmin" in _said(r)
    assert source["trace_cpu_seconds"] >= 0  # recorded with the observations
    r = _run("trace", "-o", tmp_path / "p.npz", "--images", 1, "--resolution", 4, "--spp", 1, "-q",
             "--inner", '[{"scale": 0.3, "albedo": [0, 0, 0]}]', "--noise-check", 0,
             "--checkpoint", tmp_path / "p.ckpt", "--resume")  # no checkpoint yet: a trace from the start
    assert r.exit_code == 0, r.output
    assert not (tmp_path / "p.ckpt").exists()  # removed when the trace ends
    source = Observations.load_source(tmp_path / "p.npz")
    assert "noise" not in source and source["object"]["inner"][0]["albedo"] == [0, 0, 0]


@pytest.mark.mitsuba
def test_trace_threads_set_mitsubas_threads_for_the_trace_and_restore_them(tmp_path, monkeypatch):
    """--threads N: the scene is built and traced on N Dr.Jit threads (the count the trace sees), the process's count
    restored after; without it the count is left alone."""
    mitsuba_or_skip()
    import drjit as dr

    from neumat.fit import translucent_observations

    seen = []
    collect = translucent_observations.collect_observations

    def spy(*args, **kwargs):
        seen.append(dr.thread_count())
        return collect(*args, **kwargs)
    monkeypatch.setattr(translucent_observations, "collect_observations", spy)
    before = dr.thread_count()
    for extra in (["--threads", 1], []):
        r = _run("trace", "-o", tmp_path / "o.npz", "--images", 1, "--resolution", 4, "--spp", 1, "-q",
                 "--noise-check", 0, *extra)
        assert r.exit_code == 0, r.output
        assert dr.thread_count() == before
    assert seen == [1, before]
    assert _run("trace", "-o", tmp_path / "o.npz", "--threads", 0).exit_code != 0  # at least one


def test_trace_scene_option_errors(tmp_path, without_llvm):
    r = _run("trace", "-o", tmp_path / "o.npz", "--inner", "[{oops")
    assert r.exit_code == 2 and "--inner" in _said(r)
    r = _run("trace", "-o", tmp_path / "o.npz", "--inner", '{"scale": 0.3}')
    assert r.exit_code == 2 and "alistofobjects" in _said(r)
    r = _run("trace", "-o", tmp_path / "o.npz", "--roughness-range", "0.1")
    assert r.exit_code == 2 and "LO,HI" in _said(r)
    r = _run("trace", "-o", tmp_path / "o.npz", "--resume")
    assert r.exit_code == 2 and "--resumeneeds--checkpoint" in _said(r)


def test_fit_and_translucent_fit_are_one_fit(tmp_path):
    """`neumat translucent fit obs.npz` is the old name of `neumat fit obs.npz --model neupress`: one bounds rule
    (`set_bounds_from`: the object's box recorded in the file, here larger than the observed points', and without one
    the observed points' box), the same weights and the same report (held-back error) in the header; both list
    syntaxes (a,b and JSON) are read by both."""
    g = torch.Generator().manual_seed(0)
    x = torch.nn.functional.normalize(torch.randn(64, 3, generator=g), dim=-1)
    obs = Observations(x, x.clone(), x.clone(), x.flip(0), torch.rand(64, 3, generator=g))
    box = [[-2.0, -1.5, -1.0], [2.0, 1.5, 1.0]]
    obs.save(tmp_path / "o.npz", source={"bbox": box})
    obs.save(tmp_path / "plain.npz")
    small = ["--steps", 2, "--device", "cpu", "--set", "features=4", "--set", "width=4", "--set", "layers=1",
             "--set", "batch_size=8", "--set", "sampler_batch=2", "--set", "sampler_hidden=4"]
    lists = {"fit": ["--set", "grid=2,4"], "translucent": ["--set", "grid=[2,4]"]}  # either list syntax
    for name, want in (("o", torch.tensor(box)), ("plain", torch.stack([x.min(0).values, x.max(0).values]))):
        src = tmp_path / f"{name}.npz"
        r = CliRunner().invoke(app, list(map(str, ["fit", src, "--model", "neupress", "-q", *small,
                                                   *lists["fit"], "-o", tmp_path / f"{name}_fit.nmat"])))
        assert r.exit_code == 0, r.output
        r = _run("fit", src, "-q", *small, *lists["translucent"], "-o", tmp_path / f"{name}_translucent.nmat")
        assert r.exit_code == 0, r.output
        a, b = (load_model(tmp_path / f"{name}_{k}.nmat") for k in ("fit", "translucent"))
        assert torch.equal(a.box_min, b.box_min) and torch.equal(a.box_max, b.box_max)
        assert torch.allclose(a.box_min, want[0]) and torch.allclose(a.box_max, want[1])
        assert all(torch.equal(t, b.state_dict()[k]) for k, t in a.state_dict().items())
        ma, mb = (read_header(tmp_path / f"{name}_{k}.nmat")["metrics"] for k in ("fit", "translucent"))
        assert ma["validation_mse"] == mb["validation_mse"] > 0 and ma.get("sampler_kl") == mb.get("sampler_kl")
