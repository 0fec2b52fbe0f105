"""Validation helpers that turn bad tensors into clear `InputError`s at API edges."""
from __future__ import annotations

import math

import torch

from .errors import InputError


def check_shape(t: torch.Tensor, name: str, shape: tuple) -> torch.Tensor:
    """Check `t` against `shape`, where -1 matches any size. Returns `t`."""
    if not isinstance(t, torch.Tensor):
        raise InputError(f"{name}: expected a torch.Tensor of shape {_fmt(shape)}, got {type(t).__name__}")
    if t.dim() != len(shape) or any(s != -1 and s != d for s, d in zip(shape, t.shape)):
        raise InputError(f"{name}: expected shape {_fmt(shape)}, got {tuple(t.shape)}")
    return t


def check_finite(t: torch.Tensor, name: str) -> torch.Tensor:
    """Raise if `t` holds NaN or infinity."""
    if not bool(torch.isfinite(t).all()):
        bad = int((~torch.isfinite(t)).sum())
        raise InputError(f"{name}: {bad} non-finite value(s) (NaN or inf)")
    return t


def check_directions(t: torch.Tensor, name: str, tol: float = 1e-3) -> torch.Tensor:
    """Check a (N, 3) floating-point tensor of finite unit vectors."""
    check_shape(t, name, (-1, 3))
    if not t.is_floating_point():
        raise InputError(f"{name}: expected floating-point directions, got dtype {t.dtype}")
    if t.numel():
        # one reduction and one host sync: a NaN or an infinity makes err NaN or inf, caught by the same test
        err = (torch.linalg.vector_norm(t, dim=-1) - 1).abs_().max().item()
        if not err <= tol:
            check_finite(t, name)
            raise InputError(f"{name}: directions must be unit length (max |norm - 1| = {err:.3g} > {tol})")
    return t


def check_range(t: torch.Tensor, name: str, lo: float, hi: float) -> torch.Tensor:
    """Check lo <= t <= hi elementwise."""
    check_finite(t, name)
    if t.numel() and (t.min().item() < lo or t.max().item() > hi):
        raise InputError(f"{name}: values must lie in [{lo}, {hi}], got [{t.min().item():.4g}, {t.max().item():.4g}]")
    return t


def check_int(v, name: str, lo: int = 1) -> int:
    """Check that `v` is an int (not a bool) no smaller than `lo`. Returns `v`."""
    if isinstance(v, bool) or not isinstance(v, int) or v < lo:
        raise InputError(f"{name}: expected an integer >= {lo}, got {v!r}")
    return v


def check_number(v, name: str, lo: float | None = None, strict: bool = False) -> float:
    """Check that `v` is a finite int or float (not a bool), and >= lo (> lo if `strict`) when `lo` is given.
    Returns `v`."""
    bound = "" if lo is None else f" {'>' if strict else '>='} {lo}"
    if (isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v)
            or (lo is not None and (v <= lo if strict else v < lo))):
        raise InputError(f"{name}: expected a finite number{bound}, got {v!r}")
    return v


def check_device(device, name: str = "device") -> torch.device:
    """`device` (a torch.device or a string such as "cpu", "cuda:0") as a torch.device that exists here."""
    try:
        d = torch.device(device)
    except (RuntimeError, TypeError, ValueError):
        raise InputError(f"{name}: expected a torch device such as 'cpu' or 'cuda', got {device!r}") from None
    if d.type == "cuda" and (not torch.cuda.is_available() or (d.index or 0) >= torch.cuda.device_count()):
        raise InputError(f"{name}: {device!r} asks for a CUDA GPU, but this machine has "
                         f"{torch.cuda.device_count() if torch.cuda.is_available() else 'none'}; use 'cpu'")
    if d.type not in ("cpu", "cuda", "mps") or (d.type == "mps" and not torch.backends.mps.is_available()):
        raise InputError(f"{name}: device {device!r} is not available here; use 'cpu' or 'cuda'")
    return d


def available_memory() -> int:
    """Bytes of memory available to a new allocation (MemAvailable plus free swap), or a large number where
    the system does not say."""
    try:
        info = dict(line.split(":", 1) for line in open("/proc/meminfo").read().splitlines() if ":" in line)
        return 1024 * (int(info["MemAvailable"].split()[0]) + int(info.get("SwapFree", "0 kB").split()[0]))
    except (OSError, KeyError, ValueError):
        return 1 << 62


def check_memory(nbytes: int, what: str) -> None:
    """Raise InputError before allocating when `nbytes` exceeds the available memory; `what` names the
    request (for example "render --resolution 100000: 1e10 pixels")."""
    free = available_memory()
    if nbytes > free:
        raise InputError(f"{what} needs about {nbytes / 2 ** 30:.3g} GiB of memory, "
                         f"{free / 2 ** 30:.3g} GiB are available; choose a smaller size")


def _fmt(shape: tuple) -> str:
    return "(" + ", ".join("N" if s == -1 else str(s) for s in shape) + ")"
