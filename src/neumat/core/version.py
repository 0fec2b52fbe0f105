"""The package version (re-exported as `neumat.__version__`); modules inside the package import it from here."""
__version__ = "0.1.0"
