"""Exception types. Every error raised on bad user input derives from `NeumatError`."""


class NeumatError(Exception):
    """Base class of all neumat errors."""


class InputError(NeumatError, ValueError):
    """An argument, file or config is malformed; the message names it and what was expected."""


class UnknownNameError(NeumatError, KeyError):
    """A registry lookup failed; the message lists close matches."""

    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0]) if self.args else ""


class DataFormatError(InputError):
    """A file is truncated, has a wrong header or an inconsistent field."""
