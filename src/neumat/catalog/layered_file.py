"""Layered material descriptions (`.json`, format in `neumat.io.layered_file`) opened as a
`neumat.reflectance.layered.LayeredMaterial`; registered as the ".json" source of `open_material`."""
from __future__ import annotations

from dataclasses import fields
from pathlib import Path

from ..core.errors import InputError
from ..io.layered_file import read_coat, read_conductor, read_description, read_sheen
from ..reflectance.conductor_base import TexturedConductor
from ..reflectance.layered import Coat, LayeredMaterial, Sheen
from ..reflectance.smudge_map import smudge_map
from .open_material import open_material
from .sources import register_source


#: description files being opened, outermost first (a base that leads back to one of them is a cycle)
_opening: list[Path] = []


@register_source(".json", "layered material description", "layered-material description")
def read_layered(path: str | Path, samples: int | None = None) -> LayeredMaterial:
    """The LayeredMaterial a description file defines (`neumat.io.layered_file`); `samples` overrides its
    footprint sample count. The base is any material `open_material` opens, paths relative to the file, or a
    textured conductor (`neumat.reflectance.conductor_base.TexturedConductor`); a base that leads back to a file
    being opened (a cycle) raises InputError naming the chain."""
    key = Path(path).resolve()
    if key in _opening:
        chain = " -> ".join(str(p) for p in [*_opening[_opening.index(key):], key])
        raise InputError(f"layered material {str(path)!r}: its base leads back to itself ({chain}); expected a "
                         "chain of bases that ends in a material")
    _opening.append(key)
    try:
        return _read_layered(path, samples)
    finally:
        _opening.pop()


def _read_layered(path: str | Path, samples: int | None) -> LayeredMaterial:
    desc = read_description(path)
    path, spec, folder = desc.path, desc.spec, desc.folder
    n = int(samples if samples is not None else spec.get("samples", 256))
    base_name = str(spec["base"])
    base_path = folder / base_name
    if isinstance(spec["base"], dict):
        c = read_conductor(spec["base"], f"{path} base", folder, smudge_map)
        base = TexturedConductor(c.material, c.roughness, c.normal, eta=c.eta, k=c.k, samples=n)
    elif base_path.exists():
        options = {"max_size": int(spec["max_size"])} if "max_size" in spec and base_path.is_dir() else {}
        base = open_material(base_path, **options)
    else:
        base = open_material(base_name)
    coats = []
    for i, c in enumerate(spec.get("coats", [])):
        coat = read_coat(c, f"{path} coat {i}", folder, smudge_map)
        coats.append(Coat(**{f.name: getattr(coat, f.name) for f in fields(coat)}))
    sheen = None
    if "sheen" in spec:
        d = read_sheen(spec["sheen"], f"{path} sheen", folder, smudge_map)
        sheen = Sheen(**{f.name: getattr(d, f.name) for f in fields(d)})
    return LayeredMaterial(base, coats, samples=n, name=spec.get("name") or f"layered:{path.stem}", sheen=sheen)
