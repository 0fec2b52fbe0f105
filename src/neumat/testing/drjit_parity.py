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
    dict of the two); values read back as `drjit_eval` does."""
    import drjit as dr

    rt = _runtime(exported)

    def call(args: tuple, kwargs: dict) -> np.ndarray:
        out = rt.eval(*args, **kwargs)
        dr.eval(out)
        return np.array(out, dtype=np.float32)
    return marginal_rate(_uploaded_once(lambda part: drjit_arrays(rt, part), call), q, "drjit_evals_per_second",
                         clock, repeats)


def _uploaded_once(upload, call):
    """run(part) for `marginal_rate`: each batch size's arrays uploaded on its first call only (upload(part) ->
    (args, kwargs)), then call(args, kwargs). Uploading on every call gave the kernel fresh input variables whose
    order could change its hash, so Dr.Jit compiled it again on every other call (NeuPreSS's: 5 s a time, and its
    rate read 1.6e4 instead of 6e4 per CPU second)."""
    uploaded = {}

    def run(part: Query):
        if len(part.wi) not in uploaded:  # marginal_rate's parts are prefixes of one query set: length names them
            uploaded[len(part.wi)] = upload(part)
        return call(*uploaded[len(part.wi)])
    return run


def mitsuba_measured(path):
    """`eval(q)` -> values (N, 3) (float32, CPU) of Mitsuba 3's own `measured` plugin (llvm_ad_rgb, its current
    thread count) for the RGL file `path`: BRDF x cos, as Mitsuba's `eval` returns it. The reference neumat's RGL
    reader is checked and timed against. `eval.upload(q)` and `eval.on(uploaded)` split a call in two (the rate's
    harness uploads once)."""
    import drjit as dr

    from ..core.mitsuba import import_mitsuba

    mi = import_mitsuba()
    bsdf = mi.load_dict({"type": "measured", "filename": str(path)})
    ctx = mi.BSDFContext()

    def upload(q: Query) -> tuple:
        si = mi.SurfaceInteraction3f()
        si.wi = mi.Vector3f(np.ascontiguousarray(q.wi.T.float().cpu().numpy()))
        return si, mi.Vector3f(np.ascontiguousarray(q.wo.T.float().cpu().numpy()))

    def on(uploaded: tuple) -> torch.Tensor:
        out = bsdf.eval(ctx, *uploaded)
        dr.eval(out)
        return torch.from_numpy(np.array(out, dtype=np.float32).T.copy())

    def eval(q: Query) -> torch.Tensor:
        return on(upload(q))
    eval.upload, eval.on = upload, on
    return eval


def mitsuba_measured_evals_per_second(path, q: Query, clock: str = "wall",
                                      repeats: int = 3) -> float | dict[str, float]:
    """Evaluations per second of `mitsuba_measured(path)` at the queries q, in the harness of
    `drjit_evals_per_second` (uploaded once per batch size; the `marginal_rate`: compilation and fixed costs do
    not count)."""
    f = mitsuba_measured(path)
    return marginal_rate(_uploaded_once(lambda part: (f.upload(part),), f.on), q,
                         "mitsuba_measured_evals_per_second", clock, repeats)
