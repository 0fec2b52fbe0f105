"""The optional Mitsuba 3 dependency, loaded with the variant neumat uses (llvm_ad_rgb): `import_mitsuba()`.

Shared by the mesh scenes (`neumat.render.scenes`), the ray-traced translucent slab
(`neumat.reflectance.translucent`) and the Mitsuba plugin (`neumat.integrations.mitsuba`).
"""
from __future__ import annotations

import contextlib
import importlib.util
from typing import Iterator

from .errors import InputError
from .llvm import VARIANT, configure_llvm


def import_mitsuba(variant: str = VARIANT):
    """The `mitsuba` module with `variant` set (default llvm_ad_rgb), after `neumat.core.llvm.configure_llvm` found
    an LLVM its kernels compile with. Raises InputError when Mitsuba is missing, when the variant does not load, or,
    for an LLVM variant, when no such LLVM exists; a CUDA variant needs none (a GPU machine without LLVM >= 16 runs
    cuda_ad_rgb), though one is still chosen where present so a later LLVM variant finds it. Mitsuba is imported
    only then: importing it loads Dr.Jit's LLVM (printing Dr.Jit's own complaint when there is none)."""
    if importlib.util.find_spec("mitsuba") is None:
        raise InputError("mesh scenes need Mitsuba 3 (pip install mitsuba)")
    try:
        configure_llvm()
    except InputError:
        if not variant.startswith("cuda_"):
            raise
    try:
        import mitsuba as mi
        if mi.variant() != variant:
            mi.set_variant(variant)
    except Exception as e:  # the variant failing to load
        hint = " (CUDA variants need an NVIDIA GPU and its driver)" if variant.startswith("cuda_") else ""
        raise InputError(f"Mitsuba 3 with the {variant} variant failed to load{hint}: {type(e).__name__}: {e}") from e
    return mi


@contextlib.contextmanager
def mitsuba_threads(threads: int | None) -> Iterator[None]:
    """Dr.Jit's CPU worker threads (Mitsuba's LLVM kernels) set to `threads` inside the block, restored after (None:
    left as they are). Why: a trace of a mesh on one thread is the same file bit for bit every run, on two it is
    not (measured on the bunny: up to 2.6 % of an observation at 4096 spp; methods/neupress/NOTES.md). Loads
    Mitsuba first (`import_mitsuba`: InputError without a usable LLVM), as Dr.Jit loads its LLVM on import."""
    if threads is None:
        yield
        return
    import_mitsuba()
    import drjit as dr

    before = dr.thread_count()
    dr.set_thread_count(int(threads))
    try:
        yield
    finally:
        dr.set_thread_count(before)
