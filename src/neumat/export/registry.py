"""The export formats: name ("glsl", "slang", "web") -> `ExportFormat` (what it writes, and its function).

Each format module registers itself (`EXPORT_FORMATS.register(name)(ExportFormat(...))`); `load_formats()` imports
every module of `neumat.export` (pkgutil discovery, `neumat.core.registry.import_package_modules`, as the model
registry), so the command line (`neumat.cli.exporting`) and the Slang exporter look formats up instead of importing
them."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from ..core.registry import Registry, import_package_modules


@dataclass(frozen=True)
class ExportFormat:
    """description: what the format writes; export: its entry point (`export_glsl(model)`,
    `export_slang(model)`, `write_viewer(model_or_glsl_export, path, title)`)."""

    description: str
    export: Callable


#: format name -> ExportFormat
EXPORT_FORMATS: Registry = Registry("export format")

def load_formats() -> Registry:
    """Import every module of `neumat.export` and its subpackages (the format modules register themselves) and
    return `EXPORT_FORMATS`."""
    import_package_modules("neumat.export", recursive=True)
    return EXPORT_FORMATS
