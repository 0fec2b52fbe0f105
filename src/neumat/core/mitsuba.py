"""The optional Mitsuba 3 dependency, loaded with the variant neumat uses (llvm_ad_rgb): `import_mitsuba()`.

Shared by the mesh scenes (`neumat.render.scenes`), the ray-traced translucent slab
(`neumat.reflectance.translucent`) and the Mitsuba plugin (`neumat.integrations.mitsuba`).
"""
from __future__ import annotations

from .errors import InputError
from .llvm import VARIANT, configure_llvm


def import_mitsuba():
    """The `mitsuba` module with the llvm_ad_rgb variant set, after `neumat.core.llvm.configure_llvm` found an
    LLVM its kernels compile with. Raises InputError when Mitsuba or such an LLVM is missing."""
    try:
        import mitsuba as mi
    except ImportError as e:
        raise InputError(f"mesh scenes need Mitsuba 3 (pip install mitsuba): {e}") from e
    configure_llvm()
    try:
        if mi.variant() != VARIANT:
            mi.set_variant(VARIANT)
    except Exception as e:  # the variant failing to load
        raise InputError(f"mesh scenes need Mitsuba 3 with the {VARIANT} variant: {type(e).__name__}: {e}") from e
    return mi
