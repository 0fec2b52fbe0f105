"""Presets: named ways to fit a model, each a base recipe plus model, recipe and option overrides.

Every model has "paper" (the paper's model and recipe, sized for a GPU), "cpu" (the paper's model along the
fastest CPU path) and "recommended" (the best setting measured on our data; where nothing measured beats the
paper's, the paper's model sized to the device). A method adds or replaces presets (`Method.presets`). Every
fitting entry point defaults to `DEFAULT_PRESET`, so a fit gets what the project knows without flags.
"""
from __future__ import annotations

import difflib
from dataclasses import dataclass, field, fields
from typing import Any, Mapping

from ..core.config import config_from_dict, config_to_dict
from ..core.errors import InputError, UnknownNameError
from .method import method_for, options_class, recipe_config_for_source, recipe_for, typed_options
from .recipe import Recipe, check_recipe

#: the preset every fitting entry point uses unless told otherwise
DEFAULT_PRESET = "recommended"
#: namespaces of an override key ("model.hidden", "recipe.steps", "option.dense_warmup")
NAMESPACES = ("model", "recipe", "option")


@dataclass(frozen=True)
class Preset:
    """A named setting: `recipe` is the base recipe ("paper", "cpu" or a named one; None: "cpu" on a CPU device,
    "paper" elsewhere); `overrides` map namespaced keys to values; `by_recipe` adds overrides for one base recipe
    (a setting measured at the CPU recipe's budget need not hold at the paper's); `by_source` adds overrides for
    one kind of training source (`source_kind`)."""

    doc: str
    recipe: str | None = None
    overrides: Mapping[str, Any] = field(default_factory=dict)
    by_source: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    by_recipe: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)

    def contents(self) -> dict:
        """What the preset sets, as plain dicts (its doc left out): for hashes that must change with it."""
        return {"recipe": self.recipe, "overrides": dict(self.overrides),
                "by_source": {k: dict(v) for k, v in self.by_source.items()},
                "by_recipe": {k: dict(v) for k, v in self.by_recipe.items()}}


@dataclass
class Resolved:
    """What a preset resolves to for one fit: the model config, the recipe, and how it was chosen."""

    preset: str
    recipe_name: str
    config: Any
    recipe: Recipe
    applied: dict
    """The namespaced overrides applied on top of the base recipe: the preset's, then the caller's."""

    def describe(self) -> str:
        """One line: the preset, its base recipe and its overrides."""
        shown = ", ".join(f"{k}={v}" for k, v in self.applied.items())
        return f"preset {self.preset} (recipe {self.recipe_name}{'; ' + shown if shown else ''})"


def presets_for(model: str) -> dict[str, Preset]:
    """Every preset of model `model`: the built-in "paper", "cpu" and "recommended", replaced or extended by its
    method's presets (`neumat.fit.method.Method.presets`)."""
    method = method_for(model)
    built_in = {
        "paper": Preset("the paper's model and recipe, sized for a GPU", recipe="paper"),
        "cpu": Preset("the paper's model along the fastest CPU path we measured", recipe="cpu"),
        "recommended": Preset("the paper's model, sized to the device (nothing we measured beats it yet)"),
    }
    built_in.update({name: Preset(f"the named recipe {name!r}", recipe=name)
                     for name in method.recipes if name not in ("paper", "cpu")})
    return {**built_in, **method.presets}


def preset_named(model: str, name: str) -> Preset:
    """Preset `name` of model `model`; UnknownNameError naming its presets (and the close ones) otherwise."""
    presets = presets_for(model)
    if name not in presets:
        close = difflib.get_close_matches(name, presets, n=2)
        raise UnknownNameError(f"--preset: model {model} has no preset {name!r}"
                               + (f" (did you mean {', '.join(close)}?)" if close else "")
                               + f"; its presets: {', '.join(presets)}")
    return presets[name]


def source_kind(source: Any) -> str:
    """The kind of training source a preset's `by_source` keys: "rgl" (a measured RGL file), "merl" (a tabulated
    MERL file), "analytic" (a closed-form reference), "model" (a fitted .nmat), "samples" (sparse measurements),
    "set" (several materials: the kind of the first) or "other"."""
    from ..models.base import LearnedMaterial
    from ..reflectance.analytic import AnalyticMaterial
    from ..reflectance.measured import MerlMaterial, RglMaterial
    from .measured_samples import MeasuredSamples

    if isinstance(source, (list, tuple)):
        return source_kind(source[0]) if source else "other"
    for cls, kind in ((RglMaterial, "rgl"), (MerlMaterial, "merl"), (AnalyticMaterial, "analytic"),
                      (LearnedMaterial, "model"), (MeasuredSamples, "samples")):
        if isinstance(source, cls):
            return kind
    return "other"


def settable_keys(model: str) -> dict[str, dict[str, Any]]:
    """{namespace: {key: (type, default, dataclass field or None)}} of what `--set` can change for model `model`:
    its config fields, the recipe's fields and its recipe options (typed, or the keys of its base recipe's
    options)."""
    import typing

    from ..models.registry import model_class

    cls = model_class(model)
    out: dict[str, dict[str, Any]] = {"model": {}, "recipe": {}, "option": {}}
    defaults = {"model": cls.Config(), "recipe": recipe_for(model, "paper")}
    for ns, klass in (("model", cls.Config), ("recipe", Recipe)):
        hints = typing.get_type_hints(klass)
        for f in fields(klass):
            if f.name != "options":
                out[ns][f.name] = (hints[f.name], getattr(defaults[ns], f.name), f)
    opts = options_class(model)
    if opts is not None:
        hints, default = typing.get_type_hints(opts), opts()
        out["option"] = {f.name: (hints[f.name], getattr(default, f.name), f) for f in fields(opts)}
    else:
        out["option"] = {k: (type(v), v, None) for k, v in defaults["recipe"].options.items()}
    return out


def qualify(model: str, overrides: Mapping[str, Any]) -> dict[str, Any]:
    """`overrides` with every key namespaced ("steps" -> "recipe.steps"): a bare key must name exactly one of the
    model's config fields, recipe fields and recipe options. InputError for an unknown key (with the close
    matches) or an ambiguous one (with its qualified names)."""
    keys = settable_keys(model)
    qualified, problems = {}, []
    everything = [f"{ns}.{k}" for ns, names in keys.items() for k in names]
    for key, value in overrides.items():
        ns, _, name = key.rpartition(".")
        if ns:
            if ns in keys and name in keys[ns]:
                qualified[key] = value
                continue
            where = [key]
        else:
            where = [f"{n}.{key}" for n in NAMESPACES if key in keys[n]]
            if len(where) == 1:
                qualified[where[0]] = value
                continue
            if len(where) > 1:
                problems.append(f"{key!r} is ambiguous ({' or '.join(where)}: say which)")
                continue
        bare = [k for names in keys.values() for k in names]
        close = difflib.get_close_matches(name or key, bare, n=3, cutoff=0.6)
        hint = [q for c in close for q in everything if q.rpartition(".")[2] == c]
        problems.append(f"unknown key {key!r} of {model}" + (f" (did you mean {', '.join(hint)}?)" if hint else ""))
    if problems:
        raise InputError(f"--set: {'; '.join(problems)}; `neumat list {model}` shows every key")
    return qualified


def resolve_preset(model: str, preset: str = DEFAULT_PRESET, *, device: Any = "cpu", source: Any = None,
                   overrides: Mapping[str, Any] | None = None, seed: int | None = None) -> Resolved:
    """The model config and recipe of a fit of model `model` with `preset` on `device` (a torch device or its
    type), for `source` (its kind picks the preset's `by_source` overrides; the base recipe its `by_recipe`
    ones), with the caller's `overrides`
    (namespaced or unambiguous bare keys) on top and `seed` (the recipe's) last. Everything is checked."""
    from ..models.registry import model_class

    p = preset_named(model, preset)
    device_type = getattr(device, "type", str(device).split(":")[0])
    recipe_name = p.recipe or ("cpu" if device_type == "cpu" else "paper")
    mine = qualify(model, dict(p.overrides))
    mine.update(qualify(model, dict(p.by_recipe.get(recipe_name, {}))))
    if source is not None:
        mine.update(qualify(model, dict(p.by_source.get(source_kind(source), {}))))
    applied = {**mine, **qualify(model, dict(overrides or {}))}
    base = recipe_for(model, recipe_name)
    part = {ns: {k.partition(".")[2]: v for k, v in applied.items() if k.startswith(ns + ".")} for ns in NAMESPACES}
    options = {**base.options, **part["option"]}
    recipe = config_from_dict(Recipe, {**config_to_dict(base), **part["recipe"], "options": options})
    if seed is not None:
        recipe.seed = seed
    check_recipe(recipe)
    typed_options(model, recipe.options)
    derived = recipe_config_for_source(model, source, recipe.options) if source is not None else {}
    config = config_from_dict(model_class(model).Config, {**derived, **part["model"]})
    return Resolved(preset, recipe_name, config, recipe, applied)


def default_recipe(model: Any, source: Any, device: Any = "cpu") -> Recipe:
    """The recipe of `DEFAULT_PRESET` for an already built `model` (what `neumat.fit.trainer.fit` runs without a
    recipe); InputError when the preset sets model fields the model does not have, saying how to build it."""
    from .phase import model_name

    name = model_name(model)
    r = resolve_preset(name, DEFAULT_PRESET, device=device, source=source)
    have, want = config_to_dict(model.cfg), config_to_dict(r.config)
    differ = {k: want[k] for k in (q.partition(".")[2] for q in r.applied if q.startswith("model."))
              if want[k] != have.get(k)}
    if differ:
        raise InputError(f"fit: the {DEFAULT_PRESET} preset of {name} trains a model with "
                         f"{', '.join(f'{k}={v!r}' for k, v in differ.items())}; build it with "
                         f"neumat.fit.preset.build_fit({name!r}, source=...) or pass a recipe, e.g. "
                         f"recipe_for({name!r}, 'paper')")
    return r.recipe


def build_fit(model: str, preset: str = DEFAULT_PRESET, **kwargs):
    """A fresh model `model` and its recipe for `preset` (`resolve_preset`'s arguments), initialised after seeding
    torch with the recipe's seed; returns (model, Resolved)."""
    import torch

    from ..models.registry import model_class

    r = resolve_preset(model, preset, **kwargs)
    torch.manual_seed(r.recipe.seed)
    return model_class(model)(config=r.config), r
