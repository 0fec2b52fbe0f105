"""The model registry: every model file in `neumat.models` registers its class by name.

`MODELS.build({"type": "neubrdf", **config_fields})` builds any model from a plain dict. The model
modules are imported on first use, so registering a new model needs no edit outside its own file.
"""
from __future__ import annotations

from ..core.registry import Registry, import_package_modules

MODELS: Registry = Registry("model")

def load_all() -> Registry:
    """Import every module of `neumat.models` (each registers its models) and return the registry."""
    import_package_modules("neumat.models")
    return MODELS


def build_model(spec: dict):
    """A fresh model from `{"type": name, **config_fields}`; unknown names and keys raise."""
    return load_all().build(spec)


def model_class(name: str):
    """The registered class of model `name`."""
    return load_all().get(name)
