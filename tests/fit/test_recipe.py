"""Recipes: schedules in closed form, validation, lookup of a model's defaults."""
from __future__ import annotations

import math
from dataclasses import replace

import pytest

from neumat.core.config import config_from_dict, config_to_dict
from neumat.core.errors import InputError, UnknownNameError
from neumat.fit.recipe import Recipe, check_recipe, learning_rate
from neumat.fit.method import recipe_for


def test_step_schedule():
    r = Recipe(steps=100, batch_size=8, lr=0.1, lr_decay=0.5, lr_decay_every=30)
    assert [learning_rate(r, s, 100) for s in (0, 29, 30, 59, 60, 99)] == [0.1, 0.1, 0.05, 0.05, 0.025, 0.0125]
    assert learning_rate(replace(r, lr_decay_every=0), 99, 100) == 0.1


def test_cosine_schedule():
    r = Recipe(steps=11, batch_size=8, lr=0.1, lr_min=0.01, schedule="cosine")
    assert learning_rate(r, 0, 11) == pytest.approx(0.1)
    assert learning_rate(r, 5, 11) == pytest.approx(0.055)
    assert learning_rate(r, 10, 11) == pytest.approx(0.01)
    assert learning_rate(r, 3, 11) == pytest.approx(0.01 + 0.09 * 0.5 * (1 + math.cos(math.pi * 0.3)))


@pytest.mark.parametrize("change, match", [
    (dict(steps=-1), "steps"), (dict(batch_size=0), "batch_size"), (dict(lr=0.0), "lr"),
    (dict(ema=1.5), "ema"), (dict(betas=(0.9, 1.0)), "betas"), (dict(schedule="linear"), "schedule"),
    (dict(lr=float("nan")), "lr"), (dict(log_every=0), "log_every"), (dict(steps=2.5), "steps"),
])
def test_bad_recipe_raises(change, match):
    with pytest.raises(InputError, match=match):
        check_recipe(replace(Recipe(steps=10, batch_size=8, lr=0.1), **change))


def test_recipe_for_neubrdf_is_a_valid_copy_and_round_trips():
    r = recipe_for("neubrdf")
    check_recipe(r)
    assert (r.loss, r.queries) == ("log_cos", "cosine")
    r.steps = 1
    assert recipe_for("neubrdf").steps != 1  # callers get copies
    assert config_from_dict(Recipe, config_to_dict(r)) == r


def test_recipe_for_unknown_model_raises():
    with pytest.raises(UnknownNameError, match="no training recipe for model 'nope'"):
        recipe_for("nope")


def test_every_model_has_a_cpu_recipe_no_larger_than_the_papers():
    """recipe_for(name, "cpu") is the module's CPU_RECIPE: valid, with the paper's options (the CPU recipes of
    NeuBRDF and shared NeuBRDF set their training-path options: coarse to fine, dense warm-up, candidate
    codewords), never a larger budget
    (steps x batch) than RECIPE; "gpu" is the paper's; an unknown machine is refused."""
    from neumat.fit.method import recipe_names

    for name in recipe_names():
        cpu, paper = recipe_for(name, "cpu"), recipe_for(name, "paper")
        check_recipe(cpu)
        path = {"coarse_fraction", "dense_warmup", "vq_candidates"} if name in ("neubrdf", "shared-neubrdf") \
            else set()
        assert cpu.options.keys() == paper.options.keys() and recipe_for(name, "gpu") == paper, name
        assert {k for k in cpu.options if cpu.options[k] != paper.options[k]} <= path, name
        assert cpu.steps * cpu.batch_size <= paper.steps * paper.batch_size, name
    cpu, paper = recipe_for("neubrdf", "cpu"), recipe_for("neubrdf", "paper")
    assert cpu.steps < paper.steps and paper.options["dense_warmup"] == 0 == paper.options["coarse_fraction"]
    assert 0 < cpu.options["coarse_fraction"] <= cpu.options["dense_warmup"] < 1 and cpu.schedule == "halves"
    with pytest.raises(InputError, match="recipe 'tpu': model neubrdf has the recipes paper, cpu, dense"):
        recipe_for("neubrdf", "tpu")


def test_named_recipe_dense_is_the_cpu_recipe_on_a_direction_coded_dense_grid():
    """neubrdf's named recipe "dense": the CPU recipe's budget and schedule with the settings of the dense path
    (cosine_merl queries, log_cos_eps, direction start 10, no codebook phase, the last 20 % in the runtime form);
    its preset builds a dense model, the paper's a codebook one, and an explicit features setting wins (then the
    phases refuse it); other models have no such recipe."""
    from types import SimpleNamespace

    from neumat.fit.preset import build_fit
    from neumat.fit.method import recipe_choices

    dense, cpu = recipe_for("neubrdf", "dense"), recipe_for("neubrdf", "cpu")
    check_recipe(dense)
    assert (dense.steps, dense.batch_size, dense.schedule) == (cpu.steps, cpu.batch_size, cpu.schedule)
    assert (dense.loss, dense.queries) == ("log_cos_eps", "cosine_merl")
    assert dense.options == {**cpu.options, "dense_warmup": 0.0, "vq_candidates": 0, "direction_features": 10.0,
                             "runtime_fraction": 0.2}
    assert recipe_choices("neubrdf") == ["paper", "cpu", "dense"] and recipe_choices("ggx") == ["paper", "cpu"]
    source = SimpleNamespace()
    model, r = build_fit("neubrdf", "dense", source=source, overrides={"nside": 8})
    assert model.cfg.features == "dense" and r.recipe == dense
    model, _ = build_fit("neubrdf", "cpu", source=source, overrides={"nside": 8})
    assert model.cfg.features == "dense"  # the CPU path's dense warm-up
    model, _ = build_fit("neubrdf", "paper", source=source, overrides={"nside": 8})
    assert model.cfg.features == "vq"
    model, _ = build_fit("neubrdf", "dense", source=source, overrides={"nside": 8, "features": "vq"})
    assert model.cfg.features == "vq"
    with pytest.raises(InputError, match="recipe 'dense': model ggx has the recipes paper, cpu"):
        recipe_for("ggx", "dense")


def test_latent_pyramids_follow_the_source():
    """The latent-pyramid models size their spatial latents from the texture set (the largest power of two not
    above its smaller side), none for a source without textures; an explicit --set wins in the CLI."""
    from types import SimpleNamespace

    from neumat.fit.preset import build_fit
    from neumat.fit.method import recipe_config_for_source

    source = SimpleNamespace(textures=SimpleNamespace(size=(38, 64)))
    for name in ("multiscale", "neumip", "neumip-frame", "nbrdf-uv", "tripleplane", "ggx-mipmap",
                 "neural-appearance"):
        assert recipe_config_for_source(name, source, {})["spatial_size"] == 32, name
        assert "spatial_size" not in recipe_config_for_source(name, SimpleNamespace(), {}), name
    model, _ = build_fit("neumip", source=source)
    assert model.cfg.spatial_size == 32
    model, _ = build_fit("neumip", source=source, overrides={"spatial_size": 64})
    assert model.cfg.spatial_size == 64
