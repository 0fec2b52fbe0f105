"""The registry of analytic spec names: `@register_spec("ggx")` on a Material class makes "ggx:..." spec
strings build it (`neumat.reflectance.spec.parse_spec`). Classes register where they are defined."""
from __future__ import annotations

from typing import Callable

from ..core.errors import InputError

#: spec name -> Material class, in registration order
SPEC_MATERIALS: dict[str, type] = {}


def register_spec(name: str) -> Callable[[type], type]:
    """Class decorator registering a Material class under the lowercase spec name `name`."""
    if name != name.lower() or not name or ":" in name:
        raise InputError(f"spec registry: names are lowercase, non-empty and without ':', got {name!r}")

    def deco(cls: type) -> type:
        if name in SPEC_MATERIALS:
            raise InputError(f"spec registry: {name!r} is already registered")
        SPEC_MATERIALS[name] = cls
        return cls

    return deco
