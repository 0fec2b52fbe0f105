"""The registry of analytic spec names: `@register_spec("ggx")` on a Material class makes "ggx:..." spec
strings build it (`neumat.reflectance.spec.parse_spec`). Classes register where they are defined."""
from __future__ import annotations

from typing import Callable

from ..core.errors import InputError
from ..core.registry import Registry

#: spec name -> Material class
SPEC_MATERIALS: Registry = Registry("analytic spec")


def register_spec(name: str) -> Callable[[type], type]:
    """Class decorator registering a Material class under the lowercase spec name `name`."""
    if ":" in name:
        raise InputError(f"spec registry: names are without ':', got {name!r}")
    return SPEC_MATERIALS.register(name)
