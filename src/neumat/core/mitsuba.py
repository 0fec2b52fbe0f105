"""The optional Mitsuba 3 dependency, loaded with the variant neumat uses (llvm_ad_rgb): `import_mitsuba()`.

Shared by the mesh scenes (`neumat.render.scenes`), the ray-traced translucent slab
(`neumat.reflectance.translucent`) and the Mitsuba plugin (`neumat.integrations.mitsuba`).
"""
from __future__ import annotations

import importlib.util

from .errors import InputError
from .llvm import VARIANT, configure_llvm


def import_mitsuba():
    """The `mitsuba` module with the llvm_ad_rgb variant set, after `neumat.core.llvm.configure_llvm` found an
    LLVM its kernels compile with. Raises InputError when Mitsuba or such an LLVM is missing. Mitsuba is
    imported only then: importing it loads Dr.Jit's LLVM (printing Dr.Jit's own complaint when there is none)."""
    if importlib.util.find_spec("mitsuba") is None:
        raise InputError("mesh scenes need Mitsuba 3 (pip install mitsuba)")
    configure_llvm()
    try:
        import mitsuba as mi
        if mi.variant() != VARIANT:
            mi.set_variant(VARIANT)
    except Exception as e:  # the variant failing to load
        raise InputError(f"mesh scenes need Mitsuba 3 with the {VARIANT} variant: {type(e).__name__}: {e}") from e
    return mi
