"""Presets: every model has paper / cpu / recommended, the default is one policy, keys are namespaced and checked."""
from __future__ import annotations

import json

import pytest
import torch
from typer.testing import CliRunner

from neumat.core.config import config_to_dict
from neumat.core.errors import InputError, UnknownNameError
from neumat.fit.preset import (DEFAULT_PRESET, build_fit, default_recipe, presets_for, qualify, resolve_preset,
                               source_kind)
from neumat.fit.method import recipe_for, recipe_names
from neumat.reflectance.spec import parse_spec as parse_material_spec


def test_every_model_with_a_recipe_has_the_three_presets_and_they_resolve():
    """paper is the paper's recipe, cpu the CPU recipe (with the model fields it needs), recommended is sized to the
    device where it names no recipe; all resolve to a valid config and recipe on a CPU and on a GPU device."""
    from neumat.models.registry import load_all

    for name in (n for n in recipe_names() if n in load_all()):  # proxy-sampler's recipe trains no model
        presets = presets_for(name)
        assert {"paper", "cpu", "recommended"} <= set(presets), name
        paper = resolve_preset(name, "paper")
        assert config_to_dict(paper.recipe) == config_to_dict(recipe_for(name, "paper")), name
        assert resolve_preset(name, "cpu").recipe_name == "cpu", name
        for device in ("cpu", torch.device("cuda")):
            r = resolve_preset(name, "recommended", device=device)
            expected = presets["recommended"].recipe or ("cpu" if device == "cpu" else "paper")
            assert r.recipe_name == expected, name


def test_neubrdf_default_is_the_measured_setting_by_source_kind():
    """With no options, a MERL table or an analytic source gets exactly the setting of the published Table 3 rows
    (hd_warp, cosine_merl, log_cos_eps on the CPU path); an RGL measured file keeps the paper's queries and loss,
    where those two failed on an unseen file (src/neumat/methods/neubrdf/NOTES.md)."""
    from neumat.reflectance.measured import RglMaterial

    plastic = parse_material_spec("plastic:roughness=0.2")
    r = resolve_preset("neubrdf", device="cpu", source=plastic)
    assert r.preset == DEFAULT_PRESET == "recommended" and r.recipe_name == "cpu"
    assert (r.config.direction_inputs, r.config.features) == ("hd_warp", "dense")
    assert (r.recipe.queries, r.recipe.loss) == ("cosine_merl", "log_cos_eps")
    flags = resolve_preset("neubrdf", "cpu", device="cpu", source=plastic,
                           overrides={"direction_inputs": "hd_warp", "queries": "cosine_merl", "loss": "log_cos_eps"})
    assert config_to_dict(r.recipe) == config_to_dict(flags.recipe) and r.config == flags.config
    rgl = RglMaterial.__new__(RglMaterial)  # only its kind matters here
    assert source_kind(rgl) == "rgl" and source_kind([plastic, plastic]) == "analytic"
    r = resolve_preset("neubrdf", device="cpu", source=rgl)
    assert r.config.direction_inputs == "hd_warp"
    assert (r.recipe.queries, r.recipe.loss) == (recipe_for("neubrdf", "cpu").queries,
                                                 recipe_for("neubrdf", "cpu").loss)


def test_keys_are_namespaced_and_checked():
    """A bare key qualifies when one namespace has it; an ambiguous one names its qualified forms; an unknown one
    (or one in the wrong namespace) names the close matches; values are checked by type, choice and range."""
    assert qualify("neubrdf", {"nside": 8, "steps": 3, "dense_warmup": 0.5}) == \
        {"model.nside": 8, "recipe.steps": 3, "option.dense_warmup": 0.5}
    with pytest.raises(InputError, match=r"'seed' is ambiguous \(model.seed or recipe.seed"):
        qualify("neupress", {"seed": 1})
    assert qualify("neupress", {"model.seed": 1, "recipe.seed": 2}) == {"model.seed": 1, "recipe.seed": 2}
    with pytest.raises(InputError, match=r"unknown key 'dense_warmpu'.*did you mean option.dense_warmup"):
        qualify("neubrdf", {"dense_warmpu": 0.5})
    with pytest.raises(InputError, match=r"unknown key 'recipe.nside'.*did you mean model.nside"):
        qualify("neubrdf", {"recipe.nside": 8})
    for overrides, match in (({"dense_warmup": 1.5}, r"option.dense_warmup: expected a value in \[0, 1\), got 1.5"),
                             ({"kmeans_weights": "median"}, r"option.kmeans_weights: expected one of 'uniform', "
                                                            r"'sensitivity', got 'median'"),
                             ({"prune": 1}, r"option.prune: expected true/false"),
                             ({"fine_lr_scale": 0}, r"option.fine_lr_scale: expected a value in \(0, 1\]")):
        with pytest.raises(InputError, match=match):
            resolve_preset("neubrdf", "cpu", overrides=overrides)
    with pytest.raises(UnknownNameError, match="no preset 'recomended' \\(did you mean recommended"):
        resolve_preset("neubrdf", "recomended")


def test_python_fit_defaults_to_the_recommended_recipe_and_says_how_to_build_its_model():
    """trainer.fit without a recipe runs the default preset's recipe when the model has the preset's fields, and
    refuses (naming them and build_fit) when it does not."""
    from neumat.fit.trainer import fit
    from neumat.methods.neubrdf.model import NeuBRDF

    plastic = parse_material_spec("plastic:roughness=0.3")
    model, r = build_fit("neubrdf", source=plastic, overrides={"nside": 2, "index_bits": 3, "hidden": 8})
    assert default_recipe(model, plastic) == r.recipe
    result = fit(model, plastic, steps=4, progress=False)
    assert result.recipe.loss == "log_cos_eps" and result.steps == 4
    with pytest.raises(InputError, match=r"direction_inputs='hd_warp'.*build_fit\('neubrdf'"):
        fit(NeuBRDF(nside=2, index_bits=3, hidden=8), plastic, steps=2, progress=False)


def test_list_model_shows_presets_and_every_key_with_type_default_and_doc():
    from neumat.cli.main import app

    res = CliRunner().invoke(app, ["list", "neubrdf", "--json"])
    assert res.exit_code == 0, res.output
    data = json.loads(res.stdout)
    assert [p["name"] for p in data["presets"]][:3] == ["paper", "cpu", "recommended"]
    keys = {k["key"]: k for k in data["keys"]}
    assert keys["option.dense_warmup"]["range"] == "[0, 1)" and keys["option.dense_warmup"]["type"] == "float"
    assert keys["option.kmeans_weights"]["type"] == "uniform | sensitivity"
    assert keys["model.nside"]["default"] == 64 and keys["recipe.steps"]["default"] == 20000
    assert all(k["doc"] for k in data["keys"]), [k["key"] for k in data["keys"] if not k["doc"]]
    res = CliRunner().invoke(app, ["list", "neubrdff"])
    assert res.exit_code == 2 and "unknown model 'neubrdff'" in res.output


def test_list_model_documents_every_key_of_every_model():
    """Every key of every model with a recipe (config fields, recipe fields, typed recipe options) has a doc."""
    from neumat.cli.main import app
    from neumat.fit.method import recipe_names
    from neumat.models.registry import load_all

    models = [m for m in recipe_names() if m in load_all()]
    assert len(models) > 15
    undocumented = {}
    for model in models:
        res = CliRunner().invoke(app, ["list", model, "--json"])
        assert res.exit_code == 0, (model, res.output)
        missing = [k["key"] for k in json.loads(res.stdout)["keys"] if not k["doc"]]
        if missing:
            undocumented[model] = missing
    assert not undocumented, undocumented


def test_model_files_of_format_version_1_still_load(tmp_path):
    """Files written before presets (format version 1, no preset field) load as before."""
    from safetensors.torch import load_file, save_file

    from neumat.catalog.modelfile import load_model, save_model
    from neumat.io.modelfile import HEADER_KEY
    from neumat.methods.baselines.ggx import GGXFit

    path = save_model(GGXFit(), tmp_path / "new.nmat", preset={"name": "paper", "overrides": {}})
    from safetensors import safe_open

    with safe_open(str(path), "pt") as f:
        header = json.loads(f.metadata()[HEADER_KEY])
    header.pop("preset")
    header["format_version"] = 1
    old = tmp_path / "old.nmat"
    save_file(load_file(str(path)), str(old), metadata={HEADER_KEY: json.dumps(header)})
    assert isinstance(load_model(old), GGXFit)


def test_every_computing_command_takes_threads_and_one_device_default():
    """One CLI grammar: every command but list / version / data info takes --threads and --quiet; every --device
    defaults to the same resolver (cuda when torch sees a GPU, else cpu)."""
    import typer

    from neumat.cli.common import default_device, device_option
    from neumat.cli.main import app

    def commands(group, prefix=""):
        for name, sub in group.commands.items():
            yield from commands(sub, f"{prefix}{name} ") if hasattr(sub, "commands") else [(prefix + name, sub)]

    for name, command in commands(typer.main.get_command(app)):
        options = {o for p in command.params for o in p.opts}
        assert ("--threads" in options) == (name not in ("list", "version", "data info")), name
        assert ("--quiet" in options) == (name not in ("list", "version", "data info")), name
        device = [p for p in command.params if "--device" in p.opts]
        assert all(p.default is None and p.callback is not None for p in device), name
    assert device_option(None) == default_device() == ("cuda" if torch.cuda.is_available() else "cpu")


def test_model_files_without_the_new_config_keys_still_load(tmp_path):
    """NeuBRDF and SharedNeuBRDF files written before pruned_ancestor_fraction / index_lr_scale were Config fields
    load with their defaults (0.5, 10.0)."""
    from safetensors import safe_open
    from safetensors.torch import load_file, save_file

    from neumat.catalog.modelfile import load_model, save_model
    from neumat.io.modelfile import HEADER_KEY
    from neumat.methods.neubrdf.model import NeuBRDF
    from neumat.methods.neubrdf.shared_model import SharedNeuBRDF

    for model in (NeuBRDF(nside=2, index_bits=3, hidden=8), SharedNeuBRDF(nside=2, index_bits=3, hidden=8)):
        path = save_model(model, tmp_path / "new.nmat")
        with safe_open(str(path), "pt") as f:
            header = json.loads(f.metadata()[HEADER_KEY])
        for key in ("pruned_ancestor_fraction", "index_lr_scale"):
            header["config"].pop(key, None)
        old = tmp_path / "old.nmat"
        save_file(load_file(str(path)), str(old), metadata={HEADER_KEY: json.dumps(header)})
        loaded = load_model(old)
        assert type(loaded) is type(model) and loaded.cfg.index_lr_scale == 10.0
    assert load_model(tmp_path / "new.nmat").cfg == model.cfg


def test_quiet_silences_a_fit_run_by_any_command(monkeypatch, capsys):
    """A command's --quiet (neumat.cli.common.with_quiet) reaches the trainer: no progress lines while it runs, and
    the variable is gone afterwards."""
    import os

    from neumat.cli.common import QUIET_ENV, with_quiet
    from neumat.fit.trainer import fit
    from neumat.methods.baselines.naive_mlp import NaiveMLP
    from neumat.reflectance.analytic import Lambert

    monkeypatch.delenv(QUIET_ENV, raising=False)

    def command(steps: int = 2):
        fit(NaiveMLP(hidden=4), Lambert(), recipe_for("naive-mlp"), steps=steps, progress=True, device="cpu")

    with_quiet(command)(quiet=True)
    assert capsys.readouterr().err == "" and QUIET_ENV not in os.environ
    with_quiet(command)(quiet=False)
    assert "fit naive-mlp" in capsys.readouterr().err


def test_latent_texture_recommended_preset_trains_with_the_robust_loss_and_paper_and_cpu_keep_eq10():
    """The latent-texture family's default (recommended) loss is relative_l2_robust, measured no worse than Eq. 10
    on rough shared sets and without Eq. 10's polished-metal blow-ups, with gradients clipped at norm 1 (no stall
    after a loss spike); paper and cpu stay the paper's Eq. 10, unclipped
    (benchmarks/studies/multiscale/results/polished_metal_stability.md, last section; selection_free.md)."""
    for name in ("multiscale", "tripleplane", "neumip", "neumip-offset", "neumip-frame", "nbrdf-uv", "ggx-mipmap"):
        for device in ("cpu", torch.device("cuda")):
            r = resolve_preset(name, DEFAULT_PRESET, device=device)
            assert r.recipe.loss == "relative_l2_robust" and r.recipe.grad_clip == 1.0, (name, device)
            assert r.recipe_name == ("cpu" if device == "cpu" else "paper"), (name, device)
        for preset in ("paper", "cpu"):
            assert resolve_preset(name, preset).recipe.loss == "relative_l2_mix", (name, preset)
            assert resolve_preset(name, preset).recipe.grad_clip == 0, (name, preset)
        assert resolve_preset(name, overrides={"loss": "relative_l2_mix"}).recipe.loss == "relative_l2_mix", name


def test_by_recipe_overrides_apply_only_on_their_base_recipe(monkeypatch):
    """A preset's `by_recipe` overrides join its own where the fit runs that base recipe (the CPU recipe on a CPU
    device) and nowhere else; the caller's overrides still come last, and unknown keys are refused as anywhere."""
    from neumat.fit.method import method_for
    from neumat.fit.preset import Preset

    presets = method_for("nbrdf").presets
    monkeypatch.setitem(presets, "trial", Preset("a trial", overrides={"recipe.steps": 7},
                                                 by_recipe={"cpu": {"recipe.lr": 0.25}}))
    on_cpu = resolve_preset("nbrdf", "trial", device="cpu")
    assert (on_cpu.recipe.lr, on_cpu.recipe.steps) == (0.25, 7) and on_cpu.applied["recipe.lr"] == 0.25
    on_gpu = resolve_preset("nbrdf", "trial", device=torch.device("cuda"))
    assert on_gpu.recipe_name == "paper" and on_gpu.recipe.lr == recipe_for("nbrdf", "paper").lr
    assert resolve_preset("nbrdf", "trial", device="cpu", overrides={"lr": 0.5}).recipe.lr == 0.5
    monkeypatch.setitem(presets, "bad", Preset("a bad one", by_recipe={"cpu": {"recipe.lrr": 1.0}}))
    with pytest.raises(InputError, match="unknown key 'recipe.lrr'"):
        resolve_preset("nbrdf", "bad", device="cpu")
