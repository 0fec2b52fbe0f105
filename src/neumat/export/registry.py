"""The export formats: name ("glsl", "slang", "web") -> `ExportFormat` (what it writes, and its function).

Each format module registers itself (`EXPORT_FORMATS.register(name)(ExportFormat(...))`); `load_formats()` imports
every module of `neumat.export`, so `neumat export --format` iterates the formats instead of naming them. Which
models a format takes is what their methods declare (`neumat.fit.method.Method.glsl`, `Method.drjit`).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from ..core.registry import Registry, import_package_modules


@dataclass(frozen=True)
class ExportFormat:
    """description: what the format writes; export(model, precision): the export (an object whose
    `write(folder) -> Path` writes it and whose `summary(written) -> str` says what was written), refusing a model
    it cannot take before anything is written; folder: the subfolder of the output it writes into ("" = the
    output itself); models: () -> the names of the models it takes (None: those with a GLSL generator,
    `neumat.export.glsl.glsl_models`)."""

    description: str
    export: Callable
    folder: str = ""
    models: Callable | None = None

    def write(self, exported, out: Path) -> tuple[Path, str]:
        """Write `exported` under `out` (its subfolder created); returns (what was written, its summary)."""
        written = exported.write(Path(out) / self.folder if self.folder else Path(out))
        return written, exported.summary(written)


#: format name -> ExportFormat
EXPORT_FORMATS: Registry = Registry("export format")


def load_formats() -> Registry:
    """Import every module of `neumat.export` and its subpackages (the format modules register themselves) and
    return `EXPORT_FORMATS`."""
    import_package_modules("neumat.export", recursive=True)
    return EXPORT_FORMATS
