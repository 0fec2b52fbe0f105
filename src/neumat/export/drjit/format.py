"""The "drjit" export format: a model translated by its method's Dr.Jit translator (`Method.drjit`) into the files
`neumat.export.drjit.runtime` loads without torch (manifest.json and arrays.npz)."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...core.errors import InputError
from ..registry import EXPORT_FORMATS, ExportFormat
from .runtime import ARRAYS, FORMAT, FORMAT_VERSION, MANIFEST, write_export

#: export precisions: "fp16" (floats that the runtime form rounded to fp16 stored as halves: lossless) or "fp32"
PRECISIONS = ("fp16", "fp32")


@dataclass
class DrJitExport:
    """A translated model: manifest (JSON-able dict, the program and its settings) and arrays (name -> numpy)."""

    manifest: dict
    arrays: dict

    def write(self, folder: Path) -> Path:
        return write_export(folder, self.manifest, self.arrays)

    def summary(self, folder: Path) -> str:
        size = (Path(folder) / ARRAYS).stat().st_size
        return (f"wrote {folder}/{MANIFEST} and {ARRAYS} ({size:,} bytes): Dr.Jit runtime program "
                f"{self.manifest['program']!r} of a {self.manifest['model']!r} model "
                "(neumat.export.drjit.runtime.load_runtime; the Mitsuba BSDF's filename)")

    def source(self) -> tuple[dict, dict]:
        """(manifest, arrays), what `load_runtime` takes in place of a folder."""
        return self.manifest, self.arrays


def drjit_models() -> list[str]:
    """Names of the models whose method declares a Dr.Jit translator (what `export_drjit` takes)."""
    from ...fit.method import load_methods

    methods = load_methods()
    return [name for name in methods.names() if getattr(methods.get(name), "drjit", None) is not None]


def export_drjit(model, precision: str = "fp16") -> DrJitExport:
    """The Dr.Jit runtime export of `model`, whose method declares a translator (`drjit_models()`); InputError for
    any other model, or a configuration its translator refuses. precision "fp16" stores the floats the runtime
    form rounded to fp16 as halves (lossless), "fp32" as floats."""
    if precision not in PRECISIONS:
        raise InputError(f"export_drjit precision: expected one of {', '.join(PRECISIONS)}, got {precision!r}")
    from ...fit.method import load_methods

    name = getattr(model, "name", None)
    method = load_methods().get(name) if isinstance(name, str) and name in drjit_models() else None
    if method is None or (method.model is not None and not isinstance(model, method.model)):
        raise InputError(f"export_drjit: no Dr.Jit runtime for {type(model).__name__} ({name or '?'}); models with "
                         f"one: {', '.join(drjit_models())}")
    manifest, arrays = method.drjit(model)
    out = {}
    for key, value in arrays.items():
        value = np.asarray(value)
        if value.dtype.kind == "f":
            exact16 = np.array_equal(value.astype(np.float16).astype(value.dtype), value)
            value = value.astype(np.float16 if precision == "fp16" and exact16 else np.float32)
        out[key] = value
    manifest = {"format": FORMAT, "format_version": FORMAT_VERSION, "model": name, **manifest,
                "precision": precision}
    return DrJitExport(manifest, out)


EXPORT_FORMATS.register("drjit")(ExportFormat("Dr.Jit runtime (manifest.json, arrays.npz) for Mitsuba 3's kernels",
                                              export_drjit, folder="drjit", models=drjit_models))
