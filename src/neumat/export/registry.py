"""The export formats: name ("glsl", "slang", "web") -> `ExportFormat` (what it writes, and its function).

Each format module registers itself (`EXPORT_FORMATS.register(name)(ExportFormat(...))`); `load_formats()` imports
every module of `neumat.export` (pkgutil discovery, as `neumat.models.registry.load_all` does), so the command
line (`neumat.cli.exporting`) and the Slang exporter look formats up instead of importing them.
"""
from __future__ import annotations

import importlib
import pkgutil
from dataclasses import dataclass
from typing import Callable

from ..core.registry import Registry


@dataclass(frozen=True)
class ExportFormat:
    """description: what the format writes; export: its entry point (`export_glsl(model)`,
    `export_slang(model)`, `write_viewer(model_or_glsl_export, path, title)`)."""

    description: str
    export: Callable


#: format name -> ExportFormat
EXPORT_FORMATS: Registry = Registry("export format")

_loaded = False


def load_formats() -> Registry:
    """Import every module of `neumat.export` and its subpackages (the format modules register themselves) and
    return `EXPORT_FORMATS`."""
    global _loaded
    if not _loaded:
        package = importlib.import_module("neumat.export")
        for info in pkgutil.walk_packages(package.__path__, "neumat.export."):
            importlib.import_module(info.name)
        _loaded = True
    return EXPORT_FORMATS
