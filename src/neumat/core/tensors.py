"""Per-call cost of small tensor work on hot paths: constant tensors built once per value, dtype and device (a
Python number in a tensor operation is wrapped into a new tensor on every call), tensors derived from parameters
built once while the parameters stay unchanged, calls run in inference mode when autograd is off, and element-wise
chains run on cache-sized slices of rows."""
from __future__ import annotations

import functools
from dataclasses import fields
from typing import Any, Callable, Sequence

import torch
from torch.optim.optimizer import register_optimizer_step_post_hook


@functools.lru_cache(maxsize=256)
def cached_tensor(value, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    """`torch.tensor(value, dtype, device)`, built once per arguments (value: a number or nested tuples) and a plain
    tensor even when first asked for in inference mode (autograd may save it). Shared: never modify it."""
    with torch.inference_mode(False):
        return torch.tensor(value, dtype=dtype, device=device)


#: optimiser steps taken in this process (any torch optimiser): a fused step updates parameters in place without
#: bumping their version counters, so `derived_from` also rebuilds after any step
_optimiser_steps = [0]


def _count_step(optimizer, args, kwargs) -> None:
    _optimiser_steps[0] += 1


register_optimizer_step_post_hook(_count_step)

#: parameters, buffers and submodules assigned to any module in this process: `module_stamp` collects a module's
#: tensors again only after one
_registrations = [0]


def _count_registration(module, name, value) -> None:
    _registrations[0] += 1


torch.nn.modules.module.register_module_parameter_registration_hook(_count_registration)
torch.nn.modules.module.register_module_buffer_registration_hook(_count_registration)
torch.nn.modules.module.register_module_module_registration_hook(_count_registration)


class _StampTensors:
    """The tensors `module_stamp` collected for one module, and the registration count they were collected at; a
    copy of the module (deepcopy, pickle) collects its own, since these may be another module's or non-leaf tensors
    that a swap left behind (`tensors_swapped`)."""
    __slots__ = ("count", "tensors")

    def __init__(self, count: int, tensors: tuple) -> None:
        self.count, self.tensors = count, tensors

    def __deepcopy__(self, memo) -> "_StampTensors":
        return _StampTensors(-1, ())

    def __reduce__(self):
        return _StampTensors, (-1, ())


def tensors_swapped() -> None:
    """Declare that parameters or buffers were swapped without assignment (`torch.func.functional_call` writes
    `module._parameters` directly, which no registration hook sees): `module_stamp` collects every module's tensors
    anew. Call it around the swap: before the code that reads the swapped tensors, and after the restore."""
    _registrations[0] += 1


def module_stamp(module: torch.nn.Module) -> tuple:
    """What anything derived from all of `module`'s parameters and buffers depends on: the optimiser steps taken
    (`_optimiser_steps`) and each tensor's storage and in-place version; the list of tensors is collected again only
    after some module anywhere had a parameter, buffer or submodule assigned (or `tensors_swapped`). Why: a few
    microseconds for a model of twenty tensors, where `derived_from`'s per-tensor stamp through module attribute
    lookups costs several times that on every call of a shipped model."""
    kept = module.__dict__.get("_stamp_tensors")
    if kept is None or kept.count != _registrations[0]:
        kept = _StampTensors(_registrations[0], tuple(module.parameters()) + tuple(module.buffers()))
        module.__dict__["_stamp_tensors"] = kept
    tensors = kept.tensors
    return (_optimiser_steps[0], kept.count, tuple([t._version for t in tensors]),
            tuple([t.data_ptr() for t in tensors]))


def derived_from(owner: object, key: str, params: Sequence[torch.Tensor], make: Callable[[], torch.Tensor],
                 optimised: bool = True) -> torch.Tensor:
    """make(), a tensor computed from `params` alone (a preconditioned texture, a padded lookup atlas), kept on
    `owner` under `key` and reused while no gradient is wanted (autograd off or no param requires grad) and every
    param is unchanged: the same storage, shape, dtype, device and in-place version (copy_ and load_state_dict
    bump it), and no optimiser has stepped since. With a gradient wanted it is make() every time. Why: a shipped model's
    evaluation otherwise re-derives these from its parameters on every call (the latent pyramid's preconditioned atlas
    was three quarters of a multiscale evaluation of 2^16 queries). The kept tensor is plain (built outside inference
    mode, without autograd); never modify it. `optimised=False`: params are fixed data that no optimiser steps (a
    source's maps), so a training step elsewhere does not make it anew."""
    if torch.is_grad_enabled() and any(p.requires_grad for p in params):
        return make()
    stamp = (_optimiser_steps[0] if optimised else None,
             *((p.data_ptr(), p._version, tuple(p.shape), p.dtype, p.device) for p in params))
    kept = owner.__dict__.setdefault("_derived_tensors", {})
    hit = kept.get(key)
    if hit is not None and hit[0] == stamp:
        return hit[1]
    with torch.inference_mode(False), torch.no_grad():
        value = make()
    kept[key] = (stamp, value)
    return value


def inference_call(fn: Callable[..., torch.Tensor], *args) -> torch.Tensor:
    """fn(*args), a tensor, run in inference mode when autograd is off: each tensor operation then skips autograd's
    dispatch layers, about a quarter of the 1 to 1.5 us a small CPU operation costs, which is most of what a
    small batch's evaluation costs (a model's eval is some 30 to 60 such operations). The result is cloned out of
    inference mode into a plain tensor, which the caller may modify in place or give to autograd later (an
    inference tensor allows neither). With autograd on, or already in inference mode: fn(*args) as it is.
    fn must not cache tensors it creates (they would be inference tensors); `cached_tensor` is safe."""
    if torch.is_grad_enabled() or torch.is_inference_mode_enabled():
        return fn(*args)
    with torch.inference_mode():
        out = fn(*args)
    return out.clone()


#: on a GPU (any device but the CPU) `by_rows` slices are this many times the CPU's, up to DEVICE_ROWS: a GPU has
#: no cache to fit and pays a launch per kernel per slice. With the CPU's slices the cuda suite measured the torch
#: runtimes at a CPU's rates on an H200 (GGX 15 ns a query, time linear in the slices: 245 us for each of 64 slices
#: of 2^14 rows, about 50 launches each; benchmarks/results/cuda/h200.json)
DEVICE_SCALE = 128
DEVICE_ROWS = 2 ** 20


def rows_per_slice(chunk: int, device: torch.device) -> int:
    """`chunk` on the CPU; on another device chunk * DEVICE_SCALE up to DEVICE_ROWS (at least chunk): a model whose
    CPU slices are small for its wide temporaries (NeuPreSS: 512 rows) keeps proportionally smaller GPU slices."""
    return chunk if device.type == "cpu" else max(chunk, min(chunk * DEVICE_SCALE, DEVICE_ROWS))


def by_rows(fn: Callable[..., Any], chunk: int, *tensors: Any) -> Any:
    """fn(*tensors) evaluated on consecutive slices of at most `chunk` rows of `tensors` (tensors or `Query`s) on the
    CPU (`rows_per_slice` on another device), the results (tensors, or dataclasses of tensors such as `Sample`)
    concatenated along rows. Why: an element-wise chain over N rows makes N-sized temporaries that leave the cache
    once N is large; on slices that stay in cache the cost per row does not grow with N (issue 49: GGX 1.5-3x slower
    per query at 2^20 than at 2^16). Autograd flows through the slices; without it, tensor results are written into
    one preallocated output (no second copy by a concatenation)."""
    n = len(tensors[0])
    first_tensor = tensors[0] if isinstance(tensors[0], torch.Tensor) else tensors[0].wi
    chunk = rows_per_slice(chunk, first_tensor.device)
    if n <= chunk:
        return fn(*tensors)
    first = fn(*(t[:chunk] for t in tensors))
    if isinstance(first, torch.Tensor) and not torch.is_grad_enabled():
        out = first.new_empty((n, *first.shape[1:]))
        out[:chunk] = first
        for s in range(chunk, n, chunk):
            out[s:s + chunk] = fn(*(t[s:s + chunk] for t in tensors))
        return out
    parts = [first] + [fn(*(t[s:s + chunk] for t in tensors)) for s in range(chunk, n, chunk)]
    if isinstance(first, torch.Tensor):
        return torch.cat(parts)
    return type(first)(**{f.name: torch.cat([getattr(p, f.name) for p in parts]) for f in fields(first)})
