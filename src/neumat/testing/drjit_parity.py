"""Evaluate a Dr.Jit runtime export (`neumat.export.drjit`) on torch queries, for parity checks and rates against
the torch model: `drjit_eval(exported, q)` runs the runtime on Dr.Jit's LLVM backend (the LLVM that
`neumat.core.llvm` chose; Mitsuba's import sets it up) and returns the values as a torch tensor."""
from __future__ import annotations

import numpy as np
import torch

from ..core.query import Query
from .parity import marginal_rate


def drjit_available() -> bool:
    """Whether `drjit_eval` can run here: Mitsuba 3 / Dr.Jit with a usable LLVM (>= 16)."""
    from ..core.errors import InputError
    from ..core.mitsuba import import_mitsuba

    try:
        import_mitsuba()
    except (InputError, ImportError):
        return False
    return True


def _runtime(exported):
    from ..export.drjit.runtime import Runtime, load_runtime

    if isinstance(exported, Runtime):
        return exported
    return load_runtime(exported.source() if hasattr(exported, "source") else exported, "llvm")


def drjit_arrays(rt, q: Query) -> tuple:
    """The arguments of `rt.eval` for the queries q, as arrays of the runtime's backend (uploaded once: a rate
    measured on them times the runtime, not the transfers)."""
    b = rt.backend
    arr = lambda t: b.Float(np.ascontiguousarray(t.detach().cpu().float().numpy()))  # noqa: E731
    vec = lambda w: b.Array3f(*(arr(w[:, i]) for i in range(3)))  # noqa: E731
    if getattr(rt, "translucent", False):  # NeuPreSS (program "neupress"): S_hat at the object-space position q.x
        return (vec(q.wi), vec(q.wo), True), {"x": vec(q.x)}
    uv = None if q.uv is None else (arr(q.uv[:, 0]), arr(q.uv[:, 1]))
    fp = None if q.footprint is None else tuple(arr(q.footprint[:, i, j]) for i, j in ((0, 0), (0, 1), (1, 1)))
    return (vec(q.wi), vec(q.wo), True, uv, fp), {}


def drjit_eval(exported, q: Query) -> torch.Tensor:
    """Values (N, 3) (float32) of a `DrJitExport` or an export folder (loaded on LLVM), or of a loaded runtime (on
    its own backend), at the queries q: uv and the footprint where q has them (else the finest level)."""
    import drjit as dr

    rt = _runtime(exported)
    args, kwargs = drjit_arrays(rt, q)
    out = rt.eval(*args, **kwargs)
    dr.eval(out)
    return torch.from_numpy(np.array(out, dtype=np.float32).T.copy()).to(q.wi.device)


def drjit_evals_per_second(exported, q: Query, clock: str = "wall", repeats: int = 3) -> float | dict[str, float]:
    """Evaluations per second of the runtime on Dr.Jit's LLVM backend with its current thread count, the
    `marginal_rate` (kernel compilation and transfers do not count), per wall or CPU second (`clock` "both": a
    dict of the two)."""
    rt = _runtime(exported)
    return marginal_rate(lambda part: drjit_eval(rt, part), q, "drjit_evals_per_second", clock, repeats)



def mitsuba_measured(path):
    """`eval(q)` -> values (N, 3) (float32, CPU) of Mitsuba 3's own `measured` plugin (llvm_ad_rgb, its current
    thread count) for the RGL file `path`: BRDF x cos, as Mitsuba's `eval` returns it, the queries uploaded and the
    values read back on each call. The reference neumat's RGL reader is checked and timed against."""
    import drjit as dr

    from ..core.mitsuba import import_mitsuba

    mi = import_mitsuba()
    bsdf = mi.load_dict({"type": "measured", "filename": str(path)})
    ctx = mi.BSDFContext()

    def eval(q: Query) -> torch.Tensor:
        si = mi.SurfaceInteraction3f()
        si.wi = mi.Vector3f(np.ascontiguousarray(q.wi.T.float().cpu().numpy()))
        out = bsdf.eval(ctx, si, mi.Vector3f(np.ascontiguousarray(q.wo.T.float().cpu().numpy())))
        dr.eval(out)
        return torch.from_numpy(np.array(out, dtype=np.float32).T.copy())
    return eval


def mitsuba_measured_evals_per_second(path, q: Query, clock: str = "wall",
                                      repeats: int = 3) -> float | dict[str, float]:
    """Evaluations per second of `mitsuba_measured(path)` at the queries q, in the harness of
    `drjit_evals_per_second` (the `marginal_rate`: compilation and fixed costs do not count)."""
    return marginal_rate(mitsuba_measured(path), q, "mitsuba_measured_evals_per_second", clock, repeats)
