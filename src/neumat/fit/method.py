"""The method registry: one `Method` per trainable model, registered as data by its folder in `neumat.methods`.

A Method names the model class and everything the trainer, the presets, `neumat list`, the exporters and the
conformance suite need from it. `load_methods()` imports every method folder (and the modules named in the
environment variable NEUMAT_METHODS, comma-separated: methods that live outside the package), so adding a method
touches its own folder only (`neumat.models.registry.load_all` imports them).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Callable, Mapping

from ..core.config import config_from_dict
from ..core.errors import InputError, UnknownNameError
from ..core.registry import Registry
from ..models.registry import MODELS, load_all
from .recipe import Recipe


@dataclass(frozen=True)
class Method:
    """name: the model's registry name; model: its class (None for a sub-fit such as the proxy sampler);
    recipes: "paper" (the paper's, sized for a GPU), "cpu" (the paper's model on a CPU budget) and named ones;
    options: the typed recipe options (a dataclass) or None; phases(ctx): the staged training, None for one online
    phase; config_for_source(source, options): config fields that follow the source; presets: added to or
    replacing the built-in paper / cpu / recommended; glsl(model): its GLSL generator (Slang and the web viewer
    are spelled from it), None when it has no shader; drjit(model): its Dr.Jit runtime translator (model ->
    (manifest, arrays) for `neumat.export.drjit.runtime`: Mitsuba renders it natively), None when it has none; small:
    a tiny config for the conformance suite; prepare: what a fresh small model needs before it evaluates (set by
    training from the source); report(model, source, result): (metrics saved in the .nmat, a table row) a fit
    reports beyond its loss (held-back error, ...); measured: when to choose it, in one line, from our benchmarks
    (`neumat list` shows it)."""

    name: str
    model: type | None
    recipes: Mapping[str, Recipe]
    options: type | None = None
    phases: Callable | None = None
    config_for_source: Callable | None = None
    presets: Mapping[str, Any] = field(default_factory=dict)
    glsl: Callable | None = None
    drjit: Callable | None = None
    small: Mapping[str, Any] = field(default_factory=dict)
    prepare: Callable | None = None
    report: Callable | None = None
    measured: str = ""


#: model name -> Method
METHODS: Registry = Registry("method")


def register_method(method: Method) -> Method:
    """Register `method` (and its model class in `neumat.models.registry.MODELS`); returns it."""
    missing = {"paper", "cpu"} - set(method.recipes)
    if missing:
        raise InputError(f"method {method.name}: recipes need {' and '.join(sorted(missing))}")
    for key, recipe in method.recipes.items():
        if not isinstance(recipe, Recipe):
            raise InputError(f"method {method.name}: recipe {key!r} is a {type(recipe).__name__}, not a Recipe")
    METHODS.register(method.name)(method)
    if method.model is not None:
        MODELS.register(method.name)(method.model)
    return method


def load_methods() -> Registry:
    """Import every method folder of `neumat.methods` and the modules in $NEUMAT_METHODS
    (`neumat.models.registry.load_all`); returns `METHODS`."""
    load_all()
    return METHODS


def method_for(name: str) -> Method:
    """The Method of model `name`; UnknownNameError with the close matches otherwise."""
    try:
        return load_methods().get(name)
    except UnknownNameError as e:
        raise UnknownNameError(str(e).replace("unknown method", "no training recipe for model")) from None


#: machine -> recipe key: "paper" (= "gpu") the paper's recipe, "cpu" the CPU-sized one
MACHINE_RECIPES = {"paper": "paper", "gpu": "paper", "cpu": "cpu"}


def recipe_for(model_name: str, machine: str = "paper") -> Recipe:
    """A copy of model `model_name`'s recipe `machine`: "paper" (or "gpu"), "cpu" or one of its named recipes
    (InputError naming the model's choices otherwise)."""
    recipes = method_for(model_name).recipes
    key = MACHINE_RECIPES.get(machine, machine)
    if key not in recipes:
        raise InputError(f"recipe {machine!r}: model {model_name} has the recipes "
                         f"{', '.join(recipe_choices(model_name))}")
    return replace(recipes[key], options=dict(recipes[key].options))  # a copy: callers may edit it


def recipe_choices(model_name: str) -> list[str]:
    """The recipe names `recipe_for(model_name, name)` takes: "paper", "cpu" (and "gpu", the same as "paper",
    not listed), then the model's named recipes."""
    return ["paper", "cpu", *(k for k in method_for(model_name).recipes if k not in ("paper", "cpu"))]


def phases_for(model_name: str) -> Callable | None:
    """The `phases(ctx)` builder of model `model_name`, or None for a single online phase."""
    return method_for(model_name).phases


def recipe_names() -> list[str]:
    """Registry names of every method (every model with a recipe)."""
    return load_methods().names()


def options_class(model_name: str) -> type | None:
    """The typed recipe options (a dataclass, validated by `neumat.core.config`) of model `model_name`, or None
    when its options are an untyped dict or it has no method."""
    try:
        return method_for(model_name).options
    except UnknownNameError:
        return None


def typed_options(model_name: str, options: dict) -> Any:
    """`options` (a recipe's options dict) as model `model_name`'s `Options` dataclass, strictly checked (unknown
    keys, types and ranges raise InputError); the dict itself for a model without typed options."""
    cls = options_class(model_name)
    if cls is None:
        return options
    try:
        return config_from_dict(cls, options)
    except InputError as e:
        text = str(e).replace(f"{cls.__name__}: ", "").replace(f"{cls.__name__}.", "option.")
        raise InputError(f"{model_name} recipe options: {text}") from None


def recipe_config_for_source(model_name: str, source: Any, options: dict) -> dict:
    """Config defaults of model `model_name` that follow its training source and the recipe's `options` (its
    `config_for_source(source, options)`: e.g. a latent resolution from the texture size), or {}."""
    derive = method_for(model_name).config_for_source
    return dict(derive(source, options)) if derive is not None else {}
