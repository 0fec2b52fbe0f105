"""Open any material a user can name: a file the package reads, or an analytic spec string."""
from __future__ import annotations

import inspect
from pathlib import Path
from typing import Callable

from ..core.errors import InputError
from ..core.material import Material

#: file suffix -> human-readable kind
MATERIAL_SUFFIXES = {".binary": "MERL measured BRDF", ".bsdf": "RGL measured BRDF (tensor file)",
                     ".nmat": "neumat model", ".nbtf": "neumat BTF table", ".btf": "Bonn / UBO2014 BTF",
                     ".json": "layered material description"}


def open_material(name: str | Path, **kwargs) -> Material:
    """A Material from a `.binary` (MERL), `.bsdf` (RGL), `.nbtf` (BTF table), `.btf` (Bonn / UBO2014) or
    `.nmat` file, a layered-material description (`.json`, `neumat.io.layered_file`), a PBR texture-set folder
    (an SVBRDF), or an analytic spec such as
    ``ggx:roughness=0.2,fresnel=dielectric,eta=1.5``. Keyword arguments go to the reader."""
    text = str(name)
    path = Path(text)
    suffix = path.suffix.lower()
    if path.is_dir():
        from ..reflectance.svbrdf import SVBRDF
        return _read(SVBRDF.from_folder, path, kwargs, "texture-set folder")
    if suffix in MATERIAL_SUFFIXES:
        if not path.is_file():
            raise InputError(f"material file {text!r} does not exist")
        if suffix == ".binary":
            from ..reflectance.measured import MerlMaterial
            return _read(MerlMaterial.from_file, path, kwargs, "MERL file")
        if suffix == ".bsdf":
            from ..reflectance.measured import RglMaterial
            return _read(RglMaterial.from_file, path, kwargs, "RGL file")
        if suffix == ".nbtf":
            from ..reflectance.btf import read_btf
            return _read(read_btf, path, kwargs, "BTF file")
        if suffix == ".btf":
            from ..reflectance.btf import read_ubo2014
            return _read(read_ubo2014, path, kwargs, "UBO2014 BTF file")
        if suffix == ".json":
            from .layered_file import read_layered
            return _read(read_layered, path, kwargs, "layered-material description")
        from .modelfile import load_model
        return _read(load_model, path, kwargs, "model file")
    if path.exists():
        raise InputError(f"{text!r}: unsupported material file (known: {', '.join(MATERIAL_SUFFIXES)})")
    if ":" not in text and "/" in text:
        raise InputError(f"material file {text!r} does not exist")
    if kwargs:
        raise InputError(f"{text!r}: reader options {sorted(kwargs)} only apply to files and folders; "
                         "write analytic parameters into the spec string")
    from ..reflectance.spec import parse_spec
    return parse_spec(text)


def _read(reader: Callable, path: Path, kwargs: dict, kind: str) -> Material:
    """reader(path, **kwargs), with unknown option names reported instead of a TypeError."""
    params = inspect.signature(reader).parameters
    if not any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values()):
        known = [n for n, p in params.items() if p.kind is not inspect.Parameter.VAR_POSITIONAL][1:]
        unknown = sorted(set(kwargs) - set(known))
        if unknown:
            raise InputError(f"{path}: unknown reader option(s) {', '.join(unknown)} for a {kind} "
                             f"(known: {', '.join(known) or 'none'})")
    return reader(path, **kwargs)
