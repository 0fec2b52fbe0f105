"""neumat: compact learned models of complex material appearance."""
from .catalog.modelfile import load_model as load
from .catalog.open_material import open_material
from .core.errors import DataFormatError, InputError, NeumatError, UnknownNameError
from .core.material import Material
from .core.query import Query, Sample
from .core.version import __version__

__all__ = ["Material", "Query", "Sample", "NeumatError", "InputError", "DataFormatError",
           "UnknownNameError", "load", "open_material", "__version__"]
