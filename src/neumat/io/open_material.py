"""Open any material a user can name: a file the package reads, or an analytic spec string."""
from __future__ import annotations

from pathlib import Path

from ..core.errors import InputError
from ..core.material import Material

#: file suffix -> human-readable kind
MATERIAL_SUFFIXES = {".binary": "MERL measured BRDF", ".bsdf": "RGL measured BRDF (tensor file)",
                     ".nmat": "neumat model", ".nbtf": "neumat BTF table"}


def open_material(name: str | Path, **kwargs) -> Material:
    """A Material from a `.binary` (MERL), `.bsdf` (RGL), `.nbtf` (BTF table) or `.nmat` file, a PBR texture-set
    folder (an SVBRDF), or an analytic spec such as ``ggx:roughness=0.2,fresnel=dielectric,eta=1.5``.
    Keyword arguments go to the reader."""
    text = str(name)
    path = Path(text)
    suffix = path.suffix.lower()
    if path.is_dir():
        from ..reflectance.svbrdf import SVBRDF
        return SVBRDF.from_folder(path, **kwargs)
    if suffix in MATERIAL_SUFFIXES:
        if not path.is_file():
            raise InputError(f"material file {text!r} does not exist")
        if suffix == ".binary":
            from ..reflectance.measured import MerlMaterial
            return MerlMaterial.from_file(path, **kwargs)
        if suffix == ".bsdf":
            from ..reflectance.measured import RglMaterial
            return RglMaterial.from_file(path, **kwargs)
        if suffix == ".nbtf":
            from .btf import read_btf
            return read_btf(path, **kwargs)
        from .modelfile import load_model
        return load_model(path, **kwargs)
    if path.exists():
        raise InputError(f"{text!r}: unsupported material file (known: {', '.join(MATERIAL_SUFFIXES)})")
    if ":" not in text and "/" in text:
        raise InputError(f"material file {text!r} does not exist")
    from ..reflectance.spec import parse_spec
    return parse_spec(text)
