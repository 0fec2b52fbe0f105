"""neumat: compact learned models of complex material appearance."""
from .core.errors import DataFormatError, InputError, NeumatError, UnknownNameError
from .core.material import Material
from .core.query import Query, Sample

__version__ = "0.1.0"

__all__ = ["Material", "Query", "Sample", "NeumatError", "InputError", "DataFormatError",
           "UnknownNameError", "__version__"]
