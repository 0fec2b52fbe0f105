"""The material sources `open_material` knows: a registry keyed by file suffix, plus "folder" and "spec".

`SOURCES` is a `neumat.core.registry.Registry` of data records: each entry is a `Source`: a human-readable `kind`, the
`reader(path, **options)` that builds the Material and the `noun` error messages name one by. Keys are lowercase file
suffixes (".binary", ".bsdf", ...), "folder" (a PBR texture-set folder) and "spec" (an analytic spec string such as
``ggx:roughness=0.2``; its reader takes the string). A module of `neumat.catalog` may register more with
`register_source`; `load_sources()` imports them all (discovered with pkgutil,
`neumat.core.registry.import_package_modules`, as the model registry), so no entry is listed twice."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from ..core.errors import InputError
from ..core.material import Material
from ..core.registry import Registry, import_package_modules
from neumat.methods.baselines.nbrdf import nbrdf_from_keras
from ..reflectance.btf import read_btf, read_ubo2014
from ..reflectance.measured import MerlMaterial, RglMaterial
from ..reflectance.spec import parse_spec
from ..reflectance.svbrdf import SVBRDF
from .modelfile import load_model

#: keys that are not file suffixes
FOLDER, SPEC = "folder", "spec"


@dataclass(frozen=True)
class Source:
    """kind: what the source is ("MERL measured BRDF"); reader: path (or spec text), **options -> Material;
    noun: how messages name one ("MERL file")."""

    kind: str
    reader: Callable[..., Material]
    noun: str


#: key (file suffix, FOLDER or SPEC) -> Source
SOURCES: Registry = Registry("material source")


def register_source(key: str, kind: str, noun: str) -> Callable[[Callable[..., Material]], Callable[..., Material]]:
    """Decorator (or call `register_source(key, kind, noun)(reader)`) registering `reader` under `key`."""
    if key != key.lower() or not (key.startswith(".") or key in (FOLDER, SPEC)):
        raise InputError(f"material source registry: keys are lowercase file suffixes, {FOLDER!r} or {SPEC!r}, "
                         f"got {key!r}")

    def deco(reader: Callable[..., Material]) -> Callable[..., Material]:
        SOURCES.register(key)(Source(kind, reader, noun))
        return reader

    return deco


def file_suffixes() -> list[str]:
    """The registered file suffixes, in registration order."""
    return [k for k, _ in load_sources().items() if k.startswith(".")]


register_source(FOLDER, "PBR texture-set folder (SVBRDF)", "texture-set folder")(SVBRDF.from_folder)
register_source(".binary", "MERL measured BRDF", "MERL file")(MerlMaterial.from_file)
register_source(".bsdf", "RGL measured BRDF (tensor file)", "RGL file")(RglMaterial.from_file)
register_source(".nmat", "neumat model", "model file")(load_model)
register_source(".nbtf", "neumat BTF table", "BTF file")(read_btf)
register_source(".btf", "Bonn / UBO2014 BTF", "UBO2014 BTF file")(read_ubo2014)
register_source(".h5", "NBRDF network of Sztrajman et al. (Keras .h5 + .json)", "NBRDF Keras network")(nbrdf_from_keras)
register_source(SPEC, "analytic spec string", "analytic spec")(parse_spec)

def load_sources() -> Registry:
    """Import every module of `neumat.catalog` (some register sources, e.g. ".json") and return `SOURCES`."""
    import_package_modules("neumat.catalog")
    return SOURCES
