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
    """run(part) for `marginal_rate`: each batch size's inputs uploaded on its first call only (upload(part) -> a
    tuple), then call(*that tuple). Uploading on every call gave the kernel fresh input variables whose order could
    change its hash, so Dr.Jit compiled it again on every other call (NeuPreSS's: 5 s a time; its rate read 1.6e4
    per CPU second for a runtime that runs 8e4)."""
    uploaded = {}

    def run(part: Query):
        if len(part.wi) not in uploaded:  # marginal_rate's parts are prefixes of one query set: length names them
            uploaded[len(part.wi)] = upload(part)
        return call(*uploaded[len(part.wi)])
    return run


class MitsubaMeasured:
    """Mitsuba 3's own `measured` plugin (llvm_ad_rgb, its current thread count) on the RGL file `path`: called on
    queries q, the values (N, 3) (float32, CPU) of its `eval`, BRDF x cos. The reference neumat's RGL reader is
    checked and timed against; `upload(q)` and `on(uploaded)` are a call's two halves (the rate uploads once)."""

    def __init__(self, path) -> None:
        from ..core.mitsuba import import_mitsuba

        self.mi = import_mitsuba()
        self.bsdf = self.mi.load_dict({"type": "measured", "filename": str(path)})
        self.ctx = self.mi.BSDFContext()

    def upload(self, q: Query) -> tuple:
        si = self.mi.SurfaceInteraction3f()
        si.wi = self.mi.Vector3f(np.ascontiguousarray(q.wi.T.float().cpu().numpy()))
        return si, self.mi.Vector3f(np.ascontiguousarray(q.wo.T.float().cpu().numpy()))

    def on(self, si, wo) -> torch.Tensor:
        import drjit as dr

        out = self.bsdf.eval(self.ctx, si, wo)
        dr.eval(out)
        return torch.from_numpy(np.array(out, dtype=np.float32).T.copy())

    def __call__(self, q: Query) -> torch.Tensor:
        return self.on(*self.upload(q))


def mitsuba_measured_evals_per_second(path, q: Query, clock: str = "wall",
                                      repeats: int = 3) -> float | dict[str, float]:
    """Evaluations per second of `MitsubaMeasured(path)` at the queries q, in the harness of
    `drjit_evals_per_second` (uploaded once per batch size; the `marginal_rate`: compilation and fixed costs do
    not count)."""
    plugin = MitsubaMeasured(path)
    return marginal_rate(_uploaded_once(plugin.upload, plugin.on), q, "mitsuba_measured_evals_per_second", clock,
                         repeats)
