"""Analytic materials from one-line spec strings: "name" or "name:key=value,key=value".

Names are looked up in `neumat.reflectance.spec_registry.SPEC_MATERIALS`, where each material class registers
its name (`@register_spec`). Values are numbers ("0.2"), RGB triples ("0.8/0.5/0.2") or names ("dielectric", "gold").
Keys are the keyword arguments of the material's constructor (`neumat.reflectance.analytic`), for example

    lambert:albedo=0.8/0.5/0.2
    ggx:roughness=0.2,fresnel=dielectric,eta=1.5
    ggx:alpha_x=0.3,alpha_y=0.05,material=gold
    plastic:diffuse=0.1/0.3/0.8,roughness=0.1,eta=1.5
    principled:base_color=0.9/0.6/0.2,metallic=1,roughness=0.4,anisotropy=0.5

`Material.describe()` of these materials returns such a string, so parse_spec(m.describe()) rebuilds m.
"""
from __future__ import annotations

import difflib
import inspect

from ..core.errors import InputError, UnknownNameError
from ..core.material import Material
from . import analytic  # noqa: F401  (its materials register their spec names)
from .spec_registry import SPEC_MATERIALS

#: names accepted by `parse_spec` (the analytic materials'; `SPEC_MATERIALS` holds any registered later too)
SPEC_NAMES: tuple[str, ...] = tuple(name for name, _ in SPEC_MATERIALS.items())


def _close(word: str, known) -> str:
    close = difflib.get_close_matches(word, list(known), n=3, cutoff=0.5)
    return f"did you mean {', '.join(close)}? " if close else ""


def _parse_value(text: str, key: str, spec: str):
    """'0.2' -> float, 'a/b/c' -> RGB tuple, anything else -> the name itself."""
    if "/" in text:
        parts = text.split("/")
        try:
            values = tuple(float(p) for p in parts)
        except ValueError:
            values = ()
        if len(values) != 3:
            raise InputError(f"spec {spec!r}: {key}={text!r} is not an RGB triple (expected three numbers a/b/c)")
        return values
    try:
        return float(text)
    except ValueError:
        return text


def parse_spec(spec: str) -> Material:
    """Build an analytic Material from a spec string (see the module docstring)."""
    if not isinstance(spec, str) or not spec.strip():
        raise InputError(f"spec: expected a non-empty string such as 'ggx:roughness=0.2', got {spec!r}")
    name, _, body = spec.strip().partition(":")
    name = name.strip().lower()
    if name not in SPEC_MATERIALS:
        raise UnknownNameError(f"spec {spec!r}: unknown material {name!r}; {_close(name, SPEC_MATERIALS)}"
                               f"(known: {', '.join(n for n, _ in SPEC_MATERIALS.items())})")
    cls = SPEC_MATERIALS[name]
    keys = [p for p in inspect.signature(cls.__init__).parameters if p != "self"]
    kwargs: dict = {}
    for item in filter(None, (s.strip() for s in body.split(","))):
        key, eq, text = (s.strip() for s in item.partition("="))
        if not eq or not key or not text:
            raise InputError(f"spec {spec!r}: expected key=value, got {item!r}")
        if key not in keys:
            raise UnknownNameError(f"spec {spec!r}: {name} has no parameter {key!r}; {_close(key, keys)}"
                                   f"(parameters: {', '.join(keys)})")
        if key in kwargs:
            raise InputError(f"spec {spec!r}: parameter {key!r} is given twice")
        kwargs[key] = _parse_value(text, key, spec)
    try:
        return cls(**kwargs)
    except (InputError, UnknownNameError) as err:
        raise type(err)(f"spec {spec!r}: {err}") from None
