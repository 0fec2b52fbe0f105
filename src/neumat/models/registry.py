"""The model registry: every model file in `neumat.models` registers its class by name.

`MODELS.build({"type": "neubrdf", **config_fields})` builds any model from a plain dict. The model
modules are imported on first use, so registering a new model needs no edit outside its own file.
"""
from __future__ import annotations

import importlib
import pkgutil

from ..core.registry import Registry

MODELS: Registry = Registry("model")

_loaded = False


def load_all() -> Registry:
    """Import every module of `neumat.models` (each registers its models) and return the registry."""
    global _loaded
    if not _loaded:
        package = importlib.import_module("neumat.models")
        for info in pkgutil.iter_modules(package.__path__):
            if info.name != "registry":
                importlib.import_module(f"neumat.models.{info.name}")
        _loaded = True
    return MODELS


def build_model(spec: dict):
    """A fresh model from `{"type": name, **config_fields}`; unknown names and keys raise."""
    return load_all().build(spec)


def model_class(name: str):
    """The registered class of model `name`."""
    return load_all().get(name)
