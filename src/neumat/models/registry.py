"""The model registry: name -> model class, filled by the method folders (`neumat.fit.method.register_method`).

`MODELS.build({"type": "neubrdf", **config_fields})` builds any model from a plain dict. The method folders are
imported on first use, so registering a new model needs no edit outside its own folder.
"""
from __future__ import annotations

import importlib
import os

from ..core.errors import InputError
from ..core.registry import Registry, import_package_modules

MODELS: Registry = Registry("model")
#: environment variable naming extra modules that register methods ("pkg.mod,other.mod"): methods kept outside
#: the package, e.g. a user's own or a test's
EXTRA_METHODS_ENV = "NEUMAT_METHODS"


def load_all() -> Registry:
    """Import every method folder of `neumat.methods` and the modules named in $NEUMAT_METHODS (each registers
    its models and methods, `neumat.fit.method.register_method`) and return the registry."""
    import_package_modules("neumat.methods", recursive=True)
    for module in filter(None, (m.strip() for m in os.environ.get(EXTRA_METHODS_ENV, "").split(","))):
        try:
            importlib.import_module(module)
        except ImportError as e:
            raise InputError(f"{EXTRA_METHODS_ENV}: cannot import {module!r} ({e})") from None
    return MODELS


def build_model(spec: dict):
    """A fresh model from `{"type": name, **config_fields}`; unknown names and keys raise."""
    return load_all().build(spec)


def model_class(name: str):
    """The registered class of model `name`."""
    return load_all().get(name)
