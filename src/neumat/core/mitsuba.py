"""The optional Mitsuba 3 dependency, loaded with the variant neumat uses (llvm_ad_rgb): `import_mitsuba()`.

Shared by the mesh scenes (`neumat.render.scenes`), the ray-traced translucent slab
(`neumat.reflectance.translucent`) and the Mitsuba plugin (`neumat.integrations.mitsuba`).
"""
from __future__ import annotations

import os
from pathlib import Path

from .errors import InputError

_LIBLLVM = Path("/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1")
_MITSUBA_VARIANT = "llvm_ad_rgb"


def import_mitsuba():
    """The `mitsuba` module with the llvm_ad_rgb variant set; DRJIT_LIBLLVM_PATH is pointed at the system
    LLVM when that file exists and the variable is unset. Raises InputError when Mitsuba is unusable."""
    if "DRJIT_LIBLLVM_PATH" not in os.environ and _LIBLLVM.is_file():
        os.environ["DRJIT_LIBLLVM_PATH"] = str(_LIBLLVM)
    try:
        import mitsuba as mi
        if mi.variant() != _MITSUBA_VARIANT:
            mi.set_variant(_MITSUBA_VARIANT)
    except Exception as e:  # ImportError, or the variant / LLVM failing to load
        raise InputError(f"mesh scenes need Mitsuba 3 with the {_MITSUBA_VARIANT} variant "
                         f"(pip install mitsuba, and an LLVM library): {type(e).__name__}: {e}") from e
    return mi
