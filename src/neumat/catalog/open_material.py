"""Open any material a user can name: a file the package reads, or an analytic spec string."""
from __future__ import annotations

import inspect
from pathlib import Path

from ..core.errors import InputError
from ..core.material import Material
from ..io.shared_data import resolve_data_path
from .sources import FOLDER, SPEC, Source, file_suffixes, load_sources


def open_material(name: str | Path, **kwargs) -> Material:
    """A Material from a `.binary` (MERL), `.bsdf` (RGL), `.nbtf` (BTF table), `.btf` (Bonn / UBO2014) or
    `.nmat` file, a layered-material description (`.json`, `neumat.catalog.layered_file`), a PBR texture-set
    folder (an SVBRDF), or an analytic spec such as
    ``ggx:roughness=0.2,fresnel=dielectric,eta=1.5``; any source of `neumat.catalog.sources.SOURCES`.
    Keyword arguments go to the reader."""
    source, what = material_source(name)
    if isinstance(what, Path):
        return _read(source, what, kwargs)
    if kwargs:
        raise InputError(f"{what!r}: reader options {sorted(kwargs)} only apply to files and folders; "
                         "write analytic parameters into the spec string")
    return source.reader(what)


def material_source(name: str | Path) -> tuple[Source, Path | str]:
    """(the source that reads `name`, its path (`neumat.io.shared_data.resolve_data_path`) or, for an analytic
    spec, its text), reading nothing: callers
    refuse a missing or unsupported file before starting work. InputError naming the problem."""
    sources = load_sources()
    text = str(name)
    path = resolve_data_path(text)  # also docs/examples/... and paths inside $NEUMAT_SHARED_DATA
    if path.is_dir():
        return sources[FOLDER], path
    suffixes = file_suffixes()
    if path.suffix.lower() in suffixes:
        if not path.is_file():
            raise InputError(f"material file {text!r} does not exist or is not a regular file")
        return sources[path.suffix.lower()], path
    if path.exists():
        raise InputError(f"{text!r}: unsupported material file (known: {', '.join(suffixes)})")
    if ":" not in text and "/" in text:
        raise InputError(f"material file {text!r} does not exist")
    return sources[SPEC], text


def _read(source: Source, path: Path, kwargs: dict) -> Material:
    """source.reader(path, **kwargs), with unknown option names reported instead of a TypeError."""
    reader = source.reader
    params = inspect.signature(reader).parameters
    if not any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values()):
        known = [n for n, p in params.items() if p.kind is not inspect.Parameter.VAR_POSITIONAL][1:]
        unknown = sorted(set(kwargs) - set(known))
        if unknown:
            raise InputError(f"{path}: unknown reader option(s) {', '.join(unknown)} for a {source.noun} "
                             f"(known: {', '.join(known) or 'none'})")
    return reader(path, **kwargs)
