"""Run an exported Slang material (`neumat.export.slang`) with slangpy, for parity checks against the torch model.

`slang_eval(export, q)` compiles the module's compute entry point `neumat_batch` for slangpy's CPU device (the
Slang compiler's C++ target, built with the system's gcc or clang; no GPU needed), packs the queries into its
`neumat_queries` buffer and returns what the material's methods computed. `SlangKernel(export)`
compiles once for repeated calls (tests, benchmarks). Needs the `slangpy` package (`pip install slangpy`).
On the CPU device resources bind only as module-level globals, which is how the module declares them.
"""
from __future__ import annotations

import functools

import numpy as np
import torch

from ..core.errors import InputError
from ..core.query import Query
from ..export.slang import ENTRY_CODES, QUERY_FLOATS, QUERY_LAYOUT, RESULT_FLOATS, SlangExport


def _slangpy():
    try:
        import slangpy
    except ImportError as e:  # pragma: no cover - slangpy is a dev dependency
        raise InputError("slang_eval needs the 'slangpy' package (pip install slangpy)") from e
    return slangpy


@functools.lru_cache(maxsize=4)
def _device(device_type: str):
    spy = _slangpy()
    spy.Logger.get().level = spy.LogLevel.error  # the CPU device warns that it pretends to support sm_6_0
    return spy, spy.Device(type=getattr(spy.DeviceType, device_type), enable_hot_reload=False)


_PROBE = """
RWStructuredBuffer<float> out_buffer;
[shader("compute")]
[numthreads(1, 1, 1)]
void probe(uint3 tid: SV_DispatchThreadID) { out_buffer[tid.x] = exp(0.0) + float(tid.x); }
"""


@functools.lru_cache(maxsize=4)
def slang_available(device_type: str = "cpu") -> bool:
    """Whether `slang_eval` can run here: slangpy is installed, a device of that type can be created and a
    tiny kernel compiles and runs on it (the CPU device compiles generated C++ with the system's gcc or clang)."""
    try:
        spy, device = _device(device_type)
        session = device.create_slang_session()
        module = session.load_module_from_source("neumat_probe", _PROBE)
        kernel = device.create_compute_kernel(session.link_program([module], [module.entry_point("probe")]))
        buffer = device.create_buffer(element_count=2, struct_size=4, usage=spy.BufferUsage.unordered_access)
        kernel.dispatch(thread_count=[2, 1, 1], vars={"out_buffer": buffer})
        return buffer.to_numpy().view(np.float32).tolist() == [1.0, 2.0]
    except Exception:  # no slangpy, no device, no C++ compiler
        return False


#: query fields each entry reads (besides wi)
_REQUIRED = {"eval": ("uv", "footprint", "wo"), "eval_lod": ("uv", "wo"), "albedo": ("uv", "footprint", "wo"),
             "sample": ("uv", "footprint"), "pdf": ("uv", "footprint", "wo"), "eval_brdf": ("wo",),
             "translucent": ("x", "wo"), "sigma": ("x", "wo"), "sample_incident": ("x", "wo", "n"),
             "incident_pdf": ("x", "wo", "n")}
#: entries whose result is one number (column 0)
_SCALAR = ("pdf", "sigma", "incident_pdf")


class SlangKernel:
    """An export's `neumat_batch` compiled on a slangpy device ("cpu" by default), its buffers uploaded."""

    def __init__(self, export: SlangExport, device_type: str = "cpu") -> None:
        spy, device = _device(device_type)
        self.spy, self.device, self.export = spy, device, export
        session = device.create_slang_session()
        module = session.load_module_from_source("neumat", export.source)
        program = session.link_program([module], [module.entry_point("neumat_batch")])
        self.kernel = device.create_compute_kernel(program)  # compiled (C++ on the CPU) at the first dispatch
        self.buffers = {name: self._buffer(np.ascontiguousarray(data, np.float16).reshape(-1, 4).view(np.uint32), 8)
                        if data.dtype == np.float16 else
                        self._buffer(np.ascontiguousarray(data, np.float32).reshape(-1, 4), 16)
                        for name, data in export.buffers.items()}  # float16: uint2 of four halves

    def _buffer(self, data: np.ndarray | None, stride: int, count: int = 0):
        usage = self.spy.BufferUsage
        if data is None:
            return self.device.create_buffer(element_count=count, struct_size=stride, usage=usage.unordered_access)
        return self.device.create_buffer(element_count=len(data), struct_size=stride, usage=usage.shader_resource,
                                         data=data)

    def run(self, entry: str, q: Query, u: torch.Tensor | None = None) -> torch.Tensor:
        """Results (N, 4) float32 on the CPU of method `entry` (a key of ENTRY_CODES the export has) at q: rgb
        (eval, eval_lod, albedo), wo (sample, for u (N, 2)) or the pdf in column 0. eval_lod reads q.lod (0 when
        absent), the others q.footprint; all need q.uv."""
        if entry not in self.export.entries:
            raise InputError(f"slang_eval entry: expected one of {', '.join(self.export.entries)} for this "
                             f"'{self.export.model}' export, got {entry!r}")
        n = len(q.wi)
        q.require(*_REQUIRED[entry], who=f"slang_eval entry {entry!r}")
        if entry in ("sample", "sample_incident") and (u is None or tuple(u.shape) != (n, 2)):
            raise InputError(f"slang_eval entry {entry!r}: expected u of shape ({n}, 2), got "
                             f"{None if u is None else tuple(u.shape)}")
        if n == 0:
            return torch.zeros(0, RESULT_FLOATS)
        packed = torch.zeros(n, QUERY_FLOATS, dtype=torch.float32)

        def put(key: str, values: torch.Tensor) -> None:
            at = QUERY_LAYOUT[key]
            values = values.detach().float().cpu().reshape(n, -1)
            packed[:, at:at + values.shape[1]] = values

        put("wi", q.wi)
        for key in ("wo", "uv", "lod", "x", "n"):
            if getattr(q, key) is not None:
                put(key, getattr(q, key))
        if q.footprint is not None:
            fp = q.footprint
            put("footprint_xx_xy_yy", torch.stack([fp[:, 0, 0], fp[:, 0, 1], fp[:, 1, 1]], -1))
        if u is not None:
            put("u", u)
        queries = self._buffer(packed.numpy().reshape(-1), 4)
        results = self._buffer(None, 4, n * RESULT_FLOATS)
        self.kernel.dispatch(thread_count=[n, 1, 1], vars={
            "neumat_queries": queries, "neumat_results": results, "neumat_count": n,
            "neumat_entry": ENTRY_CODES[entry], **self.buffers})
        out = results.to_numpy().view(np.float32).reshape(n, RESULT_FLOATS)
        return torch.from_numpy(out.copy())


def slang_eval(export: SlangExport | SlangKernel, q: Query, entry: str | None = None,
               u: torch.Tensor | None = None) -> torch.Tensor:
    """What the export's method `entry` computes at the queries q, float32 on q's device: (N, 3) for "eval"
    (q.footprint), "eval_lod" (q.lod, 0 when absent), "albedo" and "sample" (wo for u (N, 2); q.wo unused),
    (N,) for "pdf", (N, 3) for "eval_brdf" (homogeneous models: wi, wo only); NeuPreSS: (N, 3) for
    "translucent" (q.x, q.wo) and "sample_incident" (q.x, q.wo, q.n, u), (N,) for "sigma" and "incident_pdf".
    Default entry: "eval_brdf" for a homogeneous export, "translucent" for NeuPreSS, else "eval" when q has a
    footprint, else "eval_lod". export: a SlangExport (compiled
    here, on the CPU) or a SlangKernel compiled before."""
    kernel = export if isinstance(export, SlangKernel) else SlangKernel(export)
    entries = kernel.export.entries
    entry = entry or ("eval_brdf" if entries == ["eval_brdf"] else "translucent" if "translucent" in entries
                      else "eval" if q.footprint is not None else "eval_lod")
    out = kernel.run(entry, q, u)
    return (out[:, 0] if entry in _SCALAR else out[:, :3]).to(q.wi.device)


def slang_evals_per_second(export: SlangExport | SlangKernel, q: Query, clock: str = "wall",
                           repeats: int = 3) -> float | dict[str, float]:
    """Evaluations per second of `slang_eval(export, q)` (eval with q's footprint, else eval_lod), the
    `neumat.testing.parity.marginal_rate` (compilation and uploads do not count) per wall or CPU second (`clock`
    "both": a dict of the two)."""
    from .parity import marginal_rate

    kernel = export if isinstance(export, SlangKernel) else SlangKernel(export)
    return marginal_rate(lambda part: slang_eval(kernel, part), q, "slang_evals_per_second", clock, repeats)


def neupress_slang_parity(export: SlangExport, model, n: int, seed: int = 0) -> dict[str, float]:
    """`neumat.testing.parity.neupress_parity` for a NeuPreSS Slang module, on the same queries."""
    from .parity import neupress_differences, neupress_parity_queries

    q, f, sigma = neupress_parity_queries(model, n, seed)
    kernel = SlangKernel(export)
    return neupress_differences(f, sigma, slang_eval(kernel, q, "translucent"), slang_eval(kernel, q, "sigma"))
