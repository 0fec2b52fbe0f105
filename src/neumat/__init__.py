"""neumat: compact learned models of complex material appearance.

The names below load on first use (PEP 562), so that `import neumat.<module>` of a part that needs no torch (the
Dr.Jit runtime, `neumat.export.drjit.runtime`, and the native Mitsuba BSDF) does not import torch."""
from __future__ import annotations

import importlib

from .core.version import __version__

#: public name -> (module, attribute)
_LAZY = {"load": ("neumat.catalog.modelfile", "load_model"), "open_material": ("neumat.catalog.open_material",
                                                                              "open_material"),
         "DataFormatError": ("neumat.core.errors", "DataFormatError"),
         "InputError": ("neumat.core.errors", "InputError"),
         "NeumatError": ("neumat.core.errors", "NeumatError"), "UnknownNameError": ("neumat.core.errors",
                                                                                  "UnknownNameError"),
         "Material": ("neumat.core.material", "Material"), "Query": ("neumat.core.query", "Query"),
         "Sample": ("neumat.core.query", "Sample")}

__all__ = ["Material", "Query", "Sample", "NeumatError", "InputError", "DataFormatError",
           "UnknownNameError", "load", "open_material", "__version__"]


def __getattr__(name: str):
    if name in _LAZY:
        module, attribute = _LAZY[name]
        value = getattr(importlib.import_module(module), attribute)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'neumat' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_LAZY))
