"""Fused CPU kernels that evaluate models without autograd (`cpu_kernels.c`), compiled at first use: NBRDF,
NeuBRDF's runtime form, the gated multi-scale model and tripleplane, NeuMIP with nbrdf-uv, neumip-frame,
neumip-offset and neural-appearance's BRDF decoder, the GGX parameter mip-map, analytic GGX and the RGL measured
BRDFs' evaluation, and the principled SVBRDF a texture-set source evaluates its targets with.

Why: a small decoder's evaluation in torch is some 30 to 150 tensor operations (1 to 2 us of dispatch each, each a
pass over memory) over layers too narrow for sgemm to run near its speed; one C call per batch costs a few
microseconds and keeps each block of rows in registers (issue 49: NBRDF 8x and the multi-scale model 5x the torch
rate at 2^16 queries; measurements in the methods' NOTES.md).

The source is compiled with the system's C compiler (`$CC`, else `cc`) for this CPU (`-O3 -march=native`) into
`$NEUMAT_CACHE_DIR` (default `~/.cache/neumat`)/cpu_kernels/<hash>/, once per source, compiler and CPU. Where no
compiler works, or `NEUMAT_CPU_KERNELS=0`, `library()` is None and callers keep their torch path (`unavailable()`
says why). Callers use a kernel only for float32 CPU tensors with autograd off; results match the torch path
within float32 rounding (tests/nn/test_cpu_kernels.py)."""
from __future__ import annotations

import contextlib
import ctypes
import hashlib
import mmap
import os
import platform
import re
import shutil
import subprocess
import tempfile
import threading
import weakref
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from types import SimpleNamespace
from typing import Callable

import torch
from torch import nn

from neumat.core.tensors import module_stamp

SOURCE = Path(__file__).with_name("cpu_kernels.c")
FLAGS = ("-O3", "-march=native", "-mprefer-vector-width=512", "-fno-math-errno", "-fno-trapping-math", "-fPIC",
         "-shared")
MAX_WIDTH = 256
"""Widest layer (padded to a multiple of 4) the kernels' block buffers hold (`MAX_WIDTH` in the C source)."""
ACTIVATION_CODES = {nn.ReLU: 1, nn.LeakyReLU: 2, nn.SiLU: 3}
"""Hidden activations the kernels implement (leaky ReLU at torch's default slope 0.01 only)."""
PARALLEL_ROWS = 1 << 14
"""Rows from which a call is split over torch's intra-op thread count (ctypes releases the GIL)."""

_lock = threading.Lock()
_state: dict = {}


def _cpu_signature() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith(("flags", "Features")):
                return line
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _cache_dir() -> Path:
    return Path(os.environ.get("NEUMAT_CACHE_DIR") or Path.home() / ".cache" / "neumat") / "cpu_kernels"


def _compile(retry: bool = True) -> ctypes.CDLL:
    cc = os.environ.get("CC") or "cc"
    if shutil.which(cc) is None:
        raise RuntimeError(f"no C compiler ({cc!r} not found; set CC)")
    version = subprocess.run([cc, "--version"], capture_output=True, text=True, timeout=30).stdout
    key = hashlib.sha256("\0".join([SOURCE.read_text(), cc, version, *FLAGS, _cpu_signature()]).encode())
    folder = _cache_dir() / key.hexdigest()[:16]
    lib = folder / "libneumat_cpu_kernels.so"
    if not lib.exists():
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=folder, suffix=".so", delete=False) as tmp:
            partial = Path(tmp.name)
        try:
            done = subprocess.run([cc, *FLAGS, "-o", str(partial), str(SOURCE), "-lm"], capture_output=True,
                                  text=True, timeout=120)
            if done.returncode != 0:  # the first error line names the problem (the last is often a caret)
                lines = done.stderr.strip().splitlines() or ["?"]
                raise RuntimeError(f"{cc} failed: {next((x for x in lines if 'error' in x), lines[-1]).strip()}")
            partial.replace(lib)  # atomic: a concurrent process sees the whole library or none
        finally:
            partial.unlink(missing_ok=True)
    try:
        return _declared(ctypes.CDLL(str(lib)))
    except OSError:
        if not retry:
            raise
        lib.unlink(missing_ok=True)  # a damaged cached copy (an interrupted disk write): built again, once
        return _compile(retry=False)


_C_TYPES = {"long": ctypes.c_long, "int": ctypes.c_int, "float": ctypes.c_float}


def prototypes(source: str) -> dict[str, tuple[list, type | None]]:
    """The ctypes argument types and return type of each exported function of the C source (`int name(...)` or
    `void name(...)` at a line's start): pointers of any kind c_void_p, long / int / float scalars their own. Read
    from the source itself, so that the declarations cannot drift from the definitions."""
    out = {}
    for result, name, params in re.findall(r"^(int|void) (\w+)\(([^)]*)\)\s*\{", source, re.M):
        types = []
        for param in params.split(","):
            kind = param.rsplit(None, 1)[0].replace("const", "").strip()
            if "*" in param:
                types.append(ctypes.c_void_p)
            elif kind in _C_TYPES:
                types.append(_C_TYPES[kind])
            else:
                raise RuntimeError(f"cpu_kernels.c: {name}'s parameter {param.strip()!r} has no ctypes type")
        out[name] = types, ctypes.c_int if result == "int" else None
    return out


def _declared(lib: ctypes.CDLL) -> ctypes.CDLL:
    """lib with every exported kernel's argument and return types declared (`prototypes`): a call with a wrong
    argument type (a Python float for an int, a missing argument) raises ctypes.ArgumentError or TypeError instead
    of passing the C function garbage."""
    for name, (types, result) in prototypes(SOURCE.read_text()).items():
        fn = getattr(lib, name)
        fn.argtypes, fn.restype = types, result
    return lib


def library() -> ctypes.CDLL | None:
    """The compiled kernels, or None where they cannot be built or are switched off (`unavailable`)."""
    if "lib" not in _state:
        with _lock:
            if "lib" not in _state:
                if os.environ.get("NEUMAT_CPU_KERNELS", "1") == "0":
                    _state["lib"], _state["why"] = None, "switched off by NEUMAT_CPU_KERNELS=0"
                else:
                    try:
                        _state["lib"], _state["why"] = _compile(), None
                    except (OSError, RuntimeError, subprocess.SubprocessError) as e:
                        _state["lib"], _state["why"] = None, str(e).splitlines()[0]
    return _state["lib"]


def unavailable() -> str | None:
    """Why `library()` is None (None when the kernels are there)."""
    library()
    return _state["why"]


def reset() -> None:
    """Forget the loaded library and its reason, so that the next `library()` looks again (tests)."""
    with _lock:
        _state.clear()


@contextlib.contextmanager
def switched_off():
    """Within: every model evaluates on its torch path (export parity compares a shader with the formulas it was
    translated from; a kernel's own rounding is tested against float64 apart)."""
    _off.depth = getattr(_off, "depth", 0) + 1
    try:
        yield
    finally:
        _off.depth -= 1


_off = threading.local()


def usable(*tensors: torch.Tensor, owner: nn.Module | None = None) -> bool:
    """Whether a kernel may evaluate these inputs: the kernels exist and are not `switched_off`, no gradient is
    wanted of them (nor, with autograd on, of any parameter of `owner`: looked at only then, since walking a
    module's parameters costs microseconds a call), all are float32 on the CPU."""
    if getattr(_off, "depth", 0):
        return False
    if torch.is_grad_enabled() and (any(t.requires_grad for t in tensors)
                                    or (owner is not None and any(p.requires_grad for p in owner.parameters()))):
        return False
    if any(t.dtype != torch.float32 or t.device.type != "cpu" for t in tensors):
        return False
    return library() is not None


class PackedMLP:
    """An `neumat.nn.mlp.MLP`'s Linear / activation chain as the kernels read it: float32 weights (out x in, each
    layer's rows zero-padded in memory to a multiple of 4), the layers' true widths, pointer arrays. None from
    `pack` where the chain is not one the kernels implement (another activation, an output activation, a layer
    wider than MAX_WIDTH)."""

    def __init__(self, weights: list[torch.Tensor], biases: list[torch.Tensor], widths: list[int], hidden_act: int,
                 out_dim: int):
        self.weights, self.biases = weights, biases  # kept alive: the pointer arrays point into them
        self.layers = len(weights)
        self.dims = (ctypes.c_int * (self.layers + 1))(*widths)
        pointers = ctypes.c_void_p * self.layers
        self.w = pointers(*(w.data_ptr() for w in weights))
        self.b = pointers(*(b.data_ptr() for b in biases))
        self.hidden_act = hidden_act
        self.out_dim = out_dim

    @staticmethod
    def pack(layers: list[nn.Module] | nn.Sequential) -> "PackedMLP | None":
        """The chain Linear, activation, ..., Linear of `layers` packed, or None (class docstring)."""
        layers = list(layers)
        linears = [m for m in layers if isinstance(m, nn.Linear)]
        acts = [m for m in layers if not isinstance(m, nn.Linear)]
        if not linears or layers[-1] is not linears[-1] or len(acts) != len(linears) - 1:
            return None
        if any(not isinstance(layers[2 * i + 1], type(acts[0])) for i in range(len(acts))):
            return None
        code = activation_code(acts[0]) if acts else 1
        if code is None or any(activation_code(a) != code for a in acts):
            return None
        weights, biases = [], []
        for lin in linears:
            rows = -(-lin.out_features // 4) * 4
            if rows > MAX_WIDTH or lin.in_features > MAX_WIDTH:
                return None
            w = torch.zeros(rows, lin.in_features)
            w[:lin.out_features] = lin.weight.detach().float().cpu()
            b = torch.zeros(rows)
            if lin.bias is not None:
                b[:lin.out_features] = lin.bias.detach().float().cpu()
            weights.append(w)
            biases.append(b)
        widths = [linears[0].in_features] + [lin.out_features for lin in linears]
        return PackedMLP(weights, biases, widths, code, linears[-1].out_features)


def activation_code(module: nn.Module) -> int | None:
    """The kernels' code of a hidden activation module (`ACTIVATION_CODES`), None where they lack it."""
    code = ACTIVATION_CODES.get(type(module))
    return None if code == 2 and module.negative_slope != 0.01 else code


def prepared(owner: nn.Module, make: Callable[[], object]) -> object:
    """make(): what `owner`'s kernel reads besides the query (its MLP packed, tables in the kernel's layout), or None
    where the kernel does not apply to it; kept while `owner`'s parameters and buffers are unchanged
    (`neumat.core.tensors.module_stamp`) and its `cfg` is the same object. Call it with autograd off (`usable`).
    Why: everything here is derived from the parameters, and re-deriving or even re-checking it tensor by tensor
    on every call costs more than a small batch's kernel. Kept outside the module (ctypes pointers cannot be
    copied or pickled with it)."""
    stamp, cfg = module_stamp(owner), owner.__dict__.get("cfg")
    kept = _prepared.get(owner)
    if kept is not None and kept[1] is cfg and kept[0] == stamp:
        return kept[2]
    with torch.inference_mode(False), torch.no_grad():
        value = make()
    _prepared[owner] = (stamp, cfg, value)
    return value


#: what `prepared` keeps, per owner
_prepared: "weakref.WeakKeyDictionary[nn.Module, tuple]" = weakref.WeakKeyDictionary()


_pool: list = []  # [the executor, (its threads, the process that made it)]


#: kernel calls made in this process (`by_threads` counts them): a benchmark reads it to say which rows were
#: measured on a fused kernel
calls = [0]


def by_threads(run, n: int) -> None:
    """run(start, stop) over row ranges covering 0..n: one range below PARALLEL_ROWS rows or on one torch thread,
    else one per torch intra-op thread, run concurrently (each call releases the GIL inside the C kernel)."""
    calls[0] += 1
    threads = torch.get_num_threads()
    if n < PARALLEL_ROWS or threads <= 1:
        run(0, n)
        return
    if not _pool or _pool[1] != (threads, os.getpid()):  # a forked child has the pool but not its threads
        _pool[:] = [ThreadPoolExecutor(threads, thread_name_prefix="neumat-cpu-kernels"), (threads, os.getpid())]
    step = -(-n // threads)
    list(_pool[0].map(lambda s: run(s, min(s + step, n)), range(0, n, step)))


def _check(status: int) -> None:
    """The kernels' return codes: 0 done, 1 no memory for the block buffers, 2 a size beyond them."""
    if status == 2:
        raise ValueError("neumat.nn.cpu_kernels: a size beyond the kernel's buffers")
    if status != 0:
        raise MemoryError("neumat.nn.cpu_kernels: no memory for a kernel's block buffers (192 KB)")


HUGE_PAGE = 1 << 21
"""Bytes of a transparent huge page on x86-64 and most ARM64 Linux kernels (2 MB)."""


def on_huge_pages(t: torch.Tensor) -> torch.Tensor:
    """t's values (CPU), contiguous, in memory the kernel is asked to back with huge pages (Linux transparent huge
    pages: madvise(MADV_HUGEPAGE) on a private anonymous map aligned to 2 MB); t contiguous where t is under 2 MB
    or the system offers no such advice or map. Why: the latent textures the kernels read at random uv (a 1K
    latent is 32 MB) otherwise cost a TLB miss per texel on 4 KB pages (issue 49: the latent models' evaluation
    1.1-1.35x at random uv; measurements in neumat/methods/latent_mlp/NOTES.md)."""
    t = t.detach().contiguous()
    nbytes = t.numel() * t.element_size()
    advice = getattr(mmap, "MADV_HUGEPAGE", None)
    if advice is None or nbytes < HUGE_PAGE or t.device.type != "cpu":
        return t
    try:
        region = mmap.mmap(-1, nbytes + HUGE_PAGE, flags=mmap.MAP_PRIVATE | mmap.MAP_ANONYMOUS)  # shared: no THP
    except OSError:  # no address space for the map: torch's own memory will do
        return t
    try:
        region.madvise(advice)
    except OSError:  # a kernel without transparent huge pages
        region.close()
        return t
    address = ctypes.addressof(ctypes.c_char.from_buffer(region))
    out = torch.frombuffer(region, dtype=t.dtype, count=t.numel(), offset=-address % HUGE_PAGE).view(t.shape)
    out.copy_(t)
    return out


def _ptr(t: torch.Tensor, row: int = 0) -> int:
    """The address of t's row `row`, as an int (the kernels' pointer arguments are declared c_void_p, which takes
    one: a tenth of the cost of building a c_void_p, 0.9 us, of which a call passes a dozen)."""
    return t.data_ptr() + row * t.stride(0) * t.element_size() if row else t.data_ptr()


def nbrdf_eval(mlp: PackedMLP, wi: torch.Tensor, wo: torch.Tensor, half_theta: bool, fold: bool,
               exp_minus_one: bool) -> torch.Tensor:
    """NBRDF's evaluation (`neumat.methods.baselines.nbrdf`) of float32 directions (N, 3): (N, out_dim)."""
    lib = library()
    wi, wo = wi.contiguous(), wo.contiguous()
    out = torch.empty(len(wi), mlp.out_dim)
    fn = lib.nbrdf_eval

    def run(start: int, stop: int) -> None:
        _check(fn(_ptr(wi, start), _ptr(wo, start), ctypes.c_long(stop - start), mlp.layers, mlp.dims, mlp.w, mlp.b,
                  mlp.hidden_act, int(half_theta), int(fold), int(exp_minus_one), mlp.out_dim, _ptr(out, start)))
    by_threads(run, len(wi))
    return out


def neubrdf_eval(mlp: PackedMLP, wi: torch.Tensor, wo: torch.Tensor, nside: int, table: torch.Tensor,
                 first_act: int, directions: torch.Tensor | None = None, warp: bool = False) -> torch.Tensor:
    """NeuBRDF's runtime form (`neumat.methods.neubrdf.model`, uniform corner weights) of float32 directions (N,
    3): (N, out_dim). table: the first-layer table (24 nside^2, hidden), float32; directions: the first layer's
    columns of `Config.direction_inputs` (hidden, 6), None without them, `warp` for "hd_warp"; first_act: the
    code of the activation after the first layer; mlp: the layers after it."""
    lib = library()
    wi, wo, table = wi.contiguous(), wo.contiguous(), table.contiguous()
    dir_w = None if directions is None else directions.detach().float().t().contiguous()  # (6, hidden)
    if dir_w is not None and dir_w.shape != (6, table.shape[1]):
        raise ValueError(f"neumat.nn.cpu_kernels.neubrdf_eval: direction columns {tuple(dir_w.shape)} for a "
                         f"first layer of {table.shape[1]}")
    dir_ptr = ctypes.c_void_p(None) if dir_w is None else _ptr(dir_w)
    out = torch.empty(len(wi), mlp.out_dim)
    fn = lib.neubrdf_eval

    def run(start: int, stop: int) -> None:
        _check(fn(_ptr(wi, start), _ptr(wo, start), ctypes.c_long(stop - start), nside, _ptr(table), table.shape[1],
                  dir_ptr, int(warp), first_act, mlp.layers, mlp.dims, mlp.w, mlp.b, mlp.hidden_act, mlp.out_dim,
                  _ptr(out, start)))
    by_threads(run, len(wi))
    return out


def neubrdf_idw_eval(mlp: PackedMLP, wi: torch.Tensor, wo: torch.Tensor, material: torch.Tensor | None, active: int,
                     nside: int, corners: tuple[torch.Tensor, torch.Tensor], slots_per_material: int, south_offset: int,
                     vertex_dirs: torch.Tensor, table: torch.Tensor, bias: torch.Tensor, first_act: int,
                     directions: torch.Tensor | None = None, warp: bool = False) -> torch.Tensor:
    """NeuBRDF with inverse-distance corner weights (the shared model's materials) of float32 directions (N, 3):
    (N, out_dim). material: int32 (N,) per row, or None for `active`; corners: the S+ and S- vertex ids (t_c, 12
    nside^2, 4) int32 (t_c = 1: one set for every material); table: the first layer's rows of every slot (t x
    slots_per_material, hidden); bias: its bias; directions, warp, first_act, mlp: as `neubrdf_eval`."""
    lib = library()
    wi, wo = wi.contiguous(), wo.contiguous()
    keep = None if material is None else material.to(torch.int32).contiguous()
    dir_w = None if directions is None else directions.detach().float().t().contiguous()
    dir_ptr = ctypes.c_void_p(None) if dir_w is None else _ptr(dir_w)
    out = torch.empty(len(wi), mlp.out_dim)
    fn = lib.neubrdf_idw_eval

    def run(start: int, stop: int) -> None:
        _check(fn(_ptr(wi, start), _ptr(wo, start), ctypes.c_long(stop - start),
                  ctypes.c_void_p(None) if keep is None else _ptr(keep, start), active, nside, _ptr(corners[0]),
                  _ptr(corners[1]), int(corners[0].shape[0] > 1), ctypes.c_long(slots_per_material),
                  ctypes.c_long(south_offset), _ptr(vertex_dirs), _ptr(table), _ptr(bias), table.shape[1], dir_ptr,
                  int(warp), first_act, mlp.layers, mlp.dims, mlp.w, mlp.b, mlp.hidden_act, mlp.out_dim,
                  _ptr(out, start)))
    by_threads(run, len(wi))
    return out


def multiscale_fits(spatial: int, half: int, diff: int, gate: int, terms: int) -> bool:
    """Whether `multiscale_eval`'s buffers hold a model of these sizes (spatial, half and difference channels, the
    polar textures' factor `gate`: D_s gated, 1 not, warp terms), as its C checks; a larger one keeps its torch
    path."""
    return spatial <= 64 and half * gate <= 1024 and diff * gate <= 1024 and terms <= 8 \
        and half + diff + spatial <= MAX_WIDTH


def neumip_fits(spatial: int, frames: int) -> bool:
    """Whether `neumip_eval`'s buffers hold a model of `spatial` latent channels and `frames` shading frames."""
    return spatial <= 64 and frames <= 4 and spatial + 6 * frames <= MAX_WIDTH


def multiscale_eval(mlp: PackedMLP, latents: LatentSource, wi: torch.Tensor, wo: torch.Tensor,
                    frame: tuple[torch.Tensor, torch.Tensor] | None,
                    warps: tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor] | None,
                    tex_h: torch.Tensor, tex_d: torch.Tensor, half_channels: int, diff_channels: int,
                    gated: bool = True) -> torch.Tensor:
    """The multi-scale gated model's decoder (`neumat.methods.latent_mlp.multiscale`, gating on) of float32
    directions (N, 3) and the spatial latents `latents`: (N, out_dim). frame: its decode layer's (weight x weight
    scale (6, D_s), bias (6,)) or None; warps: (weight, bias) of the half and the difference warp ((2 K, D_s),
    (2 K,)) or None; tex_h, tex_d: the padded polar textures channels-last, their channels ordered (D_s,
    channels): (R, P + 2, D_s x channels). Not `gated` (tripleplane): textures of the channels alone, the MLP
    reads [a_h, a_d, z]."""
    lib = library()
    wi, wo = wi.contiguous(), wo.contiguous()
    null = ctypes.c_void_p(None)
    ds = latents.channels
    rows, cols = tex_h.shape[:2]
    gate = ds if gated else 1
    if tex_h.shape[2] != half_channels * gate or tex_d.shape != (rows, cols, diff_channels * gate) \
            or not (tex_h.is_contiguous() and tex_d.is_contiguous()):
        raise ValueError(f"neumat.nn.cpu_kernels.multiscale_eval: textures {tuple(tex_h.shape)}, "
                         f"{tuple(tex_d.shape)} for {half_channels} / {diff_channels} channels x {gate}")
    terms = 0 if warps is None else warps[0].shape[0] // 2
    small = [t.contiguous() for t in (frame or ()) + (warps or ())]  # kept alive through the call
    frame_w, frame_b = (null, null) if frame is None else (_ptr(small[0]), _ptr(small[1]))
    warp = [null] * 4 if warps is None else [_ptr(t) for t in small[-4:]]
    out = torch.empty(len(wi), mlp.out_dim)
    fn = lib.multiscale_eval

    def run(start: int, stop: int) -> None:
        status = fn(ctypes.byref(latents.at(start)), _ptr(wi, start), _ptr(wo, start), ctypes.c_long(stop - start),
                    ds, frame_w, frame_b, terms, *warp, int(gated), _ptr(tex_h), half_channels, _ptr(tex_d),
                    diff_channels, rows, cols - 2, mlp.layers, mlp.dims, mlp.w, mlp.b, mlp.hidden_act, mlp.out_dim,
                    _ptr(out, start))
        _check(status)
    by_threads(run, len(wi))
    return out


class _Latents(ctypes.Structure):
    """The C struct `Latents` (cpu_kernels.c): where a kernel's spatial latents come from."""
    _fields_ = [("mode", ctypes.c_int), ("z", ctypes.c_void_p), ("uv", ctypes.c_void_p), ("lod", ctypes.c_void_p),
                ("footprint", ctypes.c_void_p), ("finest", ctypes.c_void_p), ("h", ctypes.c_int), ("w", ctypes.c_int),
                ("atlas", ctypes.c_void_p), ("Wa", ctypes.c_int), ("Ha", ctypes.c_int), ("levels", ctypes.c_int),
                ("max_probes", ctypes.c_int), ("size", ctypes.c_void_p), ("origin", ctypes.c_void_p)]


class PyramidTables:
    """A `neumat.nn.latent_texture.LatentPyramid`'s levels as the kernels read them, each made at its first use: the
    finest level padded, channels-last (1, h + 2, w + 2, D_s); the atlas channels-last (1, Ha, Wa, D_s) with each
    level's size (L, 2) int32 and origin (L, 2) float32. Kept in a model's `prepared` bundle, so they are made once
    while the pyramid is unchanged."""

    def __init__(self, pyramid) -> None:
        self.pyramid = pyramid
        self.channels = pyramid.raw[0].shape[0]
        self._finest = self._atlas = None

    def finest(self) -> torch.Tensor:
        if self._finest is None:
            with torch.inference_mode(False), torch.no_grad():
                self._finest = on_huge_pages(self.pyramid.finest_padded().permute(0, 2, 3, 1))
        return self._finest

    def atlas(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        if self._atlas is None:
            from neumat.nn.latent_texture import atlas_layout

            with torch.inference_mode(False), torch.no_grad():
                raw = self.pyramid.raw
                layout = atlas_layout(tuple(tuple(int(v) for v in t.shape[1:]) for t in raw), torch.device("cpu"))
                self._atlas = (on_huge_pages(self.pyramid.atlas().permute(0, 2, 3, 1)),
                               layout["size"].to(torch.int32).contiguous(),
                               layout["origin"].to(torch.float32).contiguous())
        return self._atlas


class LatentSource:
    """A query's spatial latents as a kernel reads them from a pyramid's `PyramidTables`: the finest level at uv (no
    footprint or lod), the trilinear lookup of the atlas at a lod, or the anisotropic filter of a footprint (the
    pyramid's three lookups, float32 step by step as there); or latents z (N, D_s) given. Holds the tensors the
    pointers point into."""

    def __init__(self, tables: PyramidTables | None = None, uv: torch.Tensor | None = None,
                 lod: torch.Tensor | None = None, footprint: torch.Tensor | None = None,
                 z: torch.Tensor | None = None) -> None:
        self.rows: dict[str, tuple[torch.Tensor, int]] = {}  # per-row tensors and their floats per row
        self.struct = _Latents()
        if z is not None:
            self.struct.mode, self.channels = 0, z.shape[1]
            self._row("z", z, z.shape[1])
            return
        self.channels = tables.channels
        self._row("uv", uv, 2)
        st = self.struct
        if lod is None and footprint is None:
            level = tables.finest()
            self.keep = [level]
            st.mode, st.finest, st.h, st.w = 1, level.data_ptr(), level.shape[1] - 2, level.shape[2] - 2
            return
        atlas, size, origin = tables.atlas()
        self.keep = [atlas, size, origin]
        st.atlas, st.Ha, st.Wa = atlas.data_ptr(), atlas.shape[1], atlas.shape[2]
        st.levels, st.max_probes, st.size, st.origin = len(size), tables.pyramid.max_probes, size.data_ptr(), \
            origin.data_ptr()
        if footprint is None:
            st.mode = 2
            self._row("lod", lod, 1)
        else:
            st.mode = 3
            self._row("footprint", footprint, 4)

    def _row(self, name: str, t: torch.Tensor, per_row: int) -> None:
        if t.dtype != torch.float32:
            raise ValueError(f"neumat.nn.cpu_kernels.LatentSource: {name} is {t.dtype}, not float32")
        self.rows[name] = (t.contiguous(), per_row)

    def at(self, start: int) -> _Latents:
        """The struct for rows from `start` on (its per-row pointers moved there)."""
        st = _Latents.from_buffer_copy(self.struct)
        for name, (t, per_row) in self.rows.items():
            setattr(st, name, t.data_ptr() + 4 * per_row * start)
        return st


def neumip_eval(mlp: PackedMLP, latents: LatentSource, wi: torch.Tensor, wo: torch.Tensor,
                frame: tuple[torch.Tensor, torch.Tensor] | None = None, rusinkiewicz: bool = False) -> torch.Tensor:
    """NeuMIP's decoder (`neumat.methods.latent_mlp.neumip`, no offset module) of float32 directions (N, 3) and the
    spatial latents `latents`: exp(MLP([z, wi, wo])), or with `rusinkiewicz` MLP([z, h, d]) (nbrdf-uv), the
    directions first in the shading frames `frame` (their decode layer's weight x weight scale (6 F, D_s), bias
    (6 F,)) if given (neumip-frame, neural-appearance: [z, wi in each frame, wo in each]); (N, out_dim), 0 below
    the horizon."""
    lib = library()
    wi, wo = wi.contiguous(), wo.contiguous()
    null = ctypes.c_void_p(None)
    small = [t.contiguous() for t in frame or ()]  # kept alive through the call
    frame_w, frame_b = (null, null) if frame is None else (_ptr(small[0]), _ptr(small[1]))
    frames = 0 if frame is None else frame[1].shape[0] // 6
    out = torch.empty(len(wi), mlp.out_dim)
    fn = lib.neumip_eval

    def run(start: int, stop: int) -> None:
        status = fn(ctypes.byref(latents.at(start)), _ptr(wi, start), _ptr(wo, start), ctypes.c_long(stop - start),
                    latents.channels, frames, frame_w, frame_b, int(rusinkiewicz), mlp.layers, mlp.dims, mlp.w,
                    mlp.b, mlp.hidden_act, mlp.out_dim, _ptr(out, start))
        _check(status)
    by_threads(run, len(wi))
    return out


def neumip_uv_eval(mlp: PackedMLP, tables: PyramidTables, wi: torch.Tensor, x: torch.Tensor, wo: torch.Tensor,
                   normal: torch.Tensor, centre: torch.Tensor, surface: bool) -> torch.Tensor:
    """NeuMIP on an object's spherical UV texture (`neumat.methods.baselines.neumip_uv`: neumip-uv, or with
    `surface` surface-brdf-uv) of float32 object-space wi, x, wo and unit normals (N, 3): (N, out_dim), the MLP's
    output clamped at 0 (surface: softplus of it times the cosine of wi, clamped at 0)."""
    lib = library()
    wi, x, wo, normal = wi.contiguous(), x.contiguous(), wo.contiguous(), normal.contiguous()
    centre = centre.detach().float().contiguous()
    level = tables.finest()
    out = torch.empty(len(wi), mlp.out_dim)
    fn = lib.neumip_uv_eval

    def run(start: int, stop: int) -> None:
        _check(fn(_ptr(level), level.shape[1] - 2, level.shape[2] - 2, tables.channels, _ptr(wi, start), _ptr(x, start),
                  _ptr(wo, start), _ptr(normal, start), ctypes.c_long(stop - start), _ptr(centre), int(surface),
                  mlp.layers, mlp.dims, mlp.w, mlp.b, mlp.hidden_act, mlp.out_dim, _ptr(out, start)))
    by_threads(run, len(wi))
    return out


#: rows up to which `NeuPreSS.eval` takes `neupress_rows` (one row at a time, 9 us a row: a call of one query 45 us
#: against torch's 180); from about 24 rows torch's sgemm, reusing each layer's weights over the rows, is faster
#: (64 rows: 584 us against 410), and a kernel of blocks of 64 rows measured half its rate at 2^16 (1.8e5 vs 3.3e5)
NEUPRESS_ROWS = 16


def neupress_rows(model, wi: torch.Tensor, x: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
    """NeuPreSS's appearance network (`neumat.methods.neupress.model.NeuPreSS.eval`) of float32 object-space wi, x,
    wo (N, 3), one row at a time: (N, 3), clamped at 0."""
    lib = library()
    t = prepared(model, lambda: _neupress_tables(model))
    wi, x, wo = wi.contiguous(), x.contiguous(), wo.contiguous()
    out = torch.empty(len(wi), 3)
    _check(lib.neupress_rows(_ptr(wi), _ptr(x), _ptr(wo), ctypes.c_long(len(wi)), t.spherical, t.box_min, t.box_size,
                             t.G, t.F, t.in_dim, t.W_first, t.b_first, t.width, t.hidden, t.W, t.b, t.skips, t.W_out,
                             t.b_out, _ptr(out)))
    calls[0] += 1
    return out


def _neupress_tables(model) -> SimpleNamespace:
    """What `neupress_rows` reads: the box, the Fourier matrix transposed (in_dim x F) and the skip MLP's layers,
    contiguous float32, with their pointers."""
    net, c = model.appearance, model.cfg
    keep = [model.box_min.float().contiguous(), (model.box_max - model.box_min).float().contiguous(),
            model.appearance_features.G.float().t().contiguous()]
    for lin in (net.first, *net.hidden, net.out):
        keep += [lin.weight.detach().float().contiguous(), lin.bias.detach().float().contiguous()]
    hidden = len(net.hidden)
    pointers = ctypes.c_void_p * max(hidden, 1)
    return SimpleNamespace(keep=keep, spherical=int(c.direction_encoding == "spherical"), box_min=_ptr(keep[0]),
                           box_size=_ptr(keep[1]), G=_ptr(keep[2]), F=keep[2].shape[1], in_dim=keep[2].shape[0],
                           W_first=_ptr(keep[3]), b_first=_ptr(keep[4]), width=net.width, hidden=hidden,
                           W=pointers(*(k.data_ptr() for k in keep[5:5 + 2 * hidden:2])),
                           b=pointers(*(k.data_ptr() for k in keep[6:6 + 2 * hidden:2])), skips=int(net.skips),
                           W_out=_ptr(keep[-2]), b_out=_ptr(keep[-1]))


def dipole_eval(model, wi: torch.Tensor, x: torch.Tensor, wo: torch.Tensor, normal: torch.Tensor,
                sigma_a: torch.Tensor, sigma_s: torch.Tensor, f_dr: float) -> torch.Tensor:
    """The dipole BSSRDF (`neumat.methods.baselines.dipole_bssrdf.DipoleBSSRDF.raw`) of float32 object-space wi, x,
    wo and normals at x (N, 3), coefficients sigma_a, sigma_s' ((N, 3), or (3,) for all): (N, 3). f_dr: the
    diffuse Fresnel reflectance at the model's index of refraction."""
    lib = library()
    t = prepared(model, lambda: SimpleNamespace(points=model.points.t().contiguous(),
                                                normals=model.normals.t().contiguous(),
                                                areas=model.areas.contiguous()))
    wi, x, wo, normal = wi.contiguous(), x.contiguous(), wo.contiguous(), normal.contiguous()
    sigma_a, sigma_s = sigma_a.detach().float().contiguous(), sigma_s.detach().float().contiguous()
    shared = int(sigma_a.dim() == 1)
    out = torch.empty(len(wi), 3)
    fn = lib.dipole_eval

    def run(start: int, stop: int) -> None:
        row = 0 if shared else start
        _check(fn(_ptr(wi, start), _ptr(x, start), _ptr(wo, start), _ptr(normal, start), ctypes.c_long(stop - start),
                  _ptr(sigma_a, row), _ptr(sigma_s, row), shared, _ptr(t.points), _ptr(t.normals), _ptr(t.areas),
                  len(t.areas), ctypes.c_float(model.cfg.ior), ctypes.c_float(f_dr), _ptr(out, start)))
    by_threads(run, len(wi))
    return out


def neumip_offset_uv(mlp: PackedMLP, offset: LatentSource, wo: torch.Tensor, size: float,
                     min_cos: float) -> torch.Tensor:
    """NeuMIP's offset module (`neumat.methods.latent_mlp.neumip.NeuMIP.offset_uv`): the lookup points uv' (N, 2) of
    float32 outgoing directions wo (N, 3), `offset` the offset pyramid's latents at the query's uv, `mlp` MLP_o."""
    lib = library()
    wo = wo.contiguous()
    out = torch.empty(len(wo), 2)
    fn = lib.neumip_offset_uv

    def run(start: int, stop: int) -> None:
        _check(fn(ctypes.byref(offset.at(start)), _ptr(wo, start), ctypes.c_long(stop - start), offset.channels,
                  ctypes.c_float(size), ctypes.c_float(min_cos), mlp.layers, mlp.dims, mlp.w, mlp.b, mlp.hidden_act,
                  _ptr(out, start)))
    by_threads(run, len(wo))
    return out


#: `ggx_eval`'s Fresnel modes (`neumat.reflectance.analytic.GGX.fresnel`)
GGX_FRESNEL = {"none": 0, "conductor": 1, "dielectric": 2, "schlick": 3}


def ggx_eval(wi: torch.Tensor, wo: torch.Tensor, alpha_x: float, alpha_y: float, fresnel: str,
             eta=(1.0, 1.0, 1.0), k=(0.0, 0.0, 0.0), f0=(0.0, 0.0, 0.0), diffuse_pi=(0.0, 0.0, 0.0)) -> torch.Tensor:
    """Analytic GGX reflection (`neumat.reflectance.analytic.GGX`) of float32 directions (N, 3) with scalar alphas,
    plus the Lambertian term diffuse_pi (albedo / pi; the fitted GGX baseline's): (N, 3), 0 unless both directions
    are up. eta, k, f0, diffuse_pi: per channel (a dielectric reads eta[0])."""
    lib = library()
    wi, wo = wi.contiguous(), wo.contiguous()
    rgb = [(ctypes.c_float * 3)(*(float(v) for v in x)) for x in (eta, k, f0, diffuse_pi)]
    out = torch.empty(len(wi), 3)
    fn = lib.ggx_eval

    def run(start: int, stop: int) -> None:
        _check(fn(_ptr(wi, start), _ptr(wo, start), ctypes.c_long(stop - start), ctypes.c_float(alpha_x),
                  ctypes.c_float(alpha_y), GGX_FRESNEL[fresnel], *rgb, _ptr(out, start)))
    by_threads(run, len(wi))
    return out


def svbrdf_eval(padded_maps: torch.Tensor, wi: torch.Tensor, wo: torch.Tensor, pts: torch.Tensor, specular: float,
                symmetrise: bool) -> torch.Tensor:
    """The principled SVBRDF's point value (`neumat.reflectance.svbrdf.SVBRDF.eval_point`) of float32 directions
    (N, 3), averaged over the positions pts (N, S, 2) of each query (S = 1: the point value): (N, 3). padded_maps:
    the source's PBR stack (1, 8, H + 2, W + 2) as `neumat.nn.latent_texture.padded_maps` keeps it (channels-last)."""
    lib = library()
    n, samples = pts.shape[0], pts.shape[1]
    h, w = padded_maps.shape[2] - 2, padded_maps.shape[3] - 2
    if padded_maps.shape[1] != 8 or not padded_maps.is_contiguous(memory_format=torch.channels_last):
        raise ValueError("svbrdf_eval: expected the padded (1, 8, H + 2, W + 2) maps in channels-last order")
    wi, wo, pts = wi.contiguous(), wo.contiguous(), pts.contiguous()
    out = torch.empty(n, 3)
    fn = lib.svbrdf_eval

    def run(start: int, stop: int) -> None:
        _check(fn(_ptr(padded_maps), h, w, _ptr(wi, start), _ptr(wo, start), _ptr(pts, start),
                  ctypes.c_long(stop - start), samples, ctypes.c_float(specular), int(symmetrise), _ptr(out, start)))
    by_threads(run, n)
    return out


def ggx_mipmap_eval(latents: LatentSource, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
    """The GGX parameter mip-map (`neumat.methods.latent_mlp.ggx_mipmap`) of float32 directions (N, 3) and its 12
    filtered parameters `latents`: (N, 3), 0 below the horizon."""
    lib = library()
    wi, wo = wi.contiguous(), wo.contiguous()
    out = torch.empty(len(wi), 3)
    fn = lib.ggx_mipmap_eval

    def run(start: int, stop: int) -> None:
        _check(fn(ctypes.byref(latents.at(start)), _ptr(wi, start), _ptr(wo, start), ctypes.c_long(stop - start),
                  _ptr(out, start)))
    by_threads(run, len(wi))
    return out


class _Table2D(ctypes.Structure):
    """The C struct `Table2D` (cpu_kernels.c): a Marginal2D's float32 tables."""
    _fields_ = [("data", ctypes.c_void_p * 3), ("H", ctypes.c_int), ("W", ctypes.c_int), ("K", ctypes.c_int),
                ("cond", ctypes.c_void_p), ("marg", ctypes.c_void_p)]


class RglTables:
    """An RGL material's warps and tables (`neumat.reflectance.measured.RglMaterial`) as `rgl_eval` reads them:
    float32, one flat array per channel; holds the tensors the structs point into."""

    def __init__(self, material) -> None:
        def table(m) -> _Table2D:
            tabs = m._tables(torch.device("cpu"), torch.float32)
            keep = [t.contiguous() for t in tabs["channels"]] + [tabs[n].contiguous() for n in ("cond", "marg")
                                                                 if n in tabs]
            self.keep += keep
            st = _Table2D(H=m.h, W=m.w, K=len(tabs["channels"]))
            for c, t in enumerate(keep[:st.K]):
                st.data[c] = t.data_ptr()
            st.cond = tabs["cond"].data_ptr() if "cond" in tabs else None
            st.marg = tabs["marg"].data_ptr() if "marg" in tabs else None
            return st

        self.keep: list[torch.Tensor] = []
        grid = material.vndf.param_values
        self.phi, self.theta = grid[0].float().contiguous(), grid[1].float().contiguous()
        self.vndf, self.rgb = table(material.vndf), table(material.rgb)
        self.ndf, self.sigma = table(material.ndf), table(material.sigma)
        self.isotropic, self.reduction, self.jacobian = material.isotropic, material.reduction, material.jacobian


def rgl_tables(material) -> RglTables:
    """`RglTables` of an RGL material, made at its first use and kept outside it (ctypes structs cannot be copied
    or pickled with the material)."""
    tables = _rgl_tables.get(material)
    if tables is None:
        tables = _rgl_tables[material] = RglTables(material)
    return tables


#: what `rgl_tables` keeps, per material
_rgl_tables: "weakref.WeakKeyDictionary[object, RglTables]" = weakref.WeakKeyDictionary()


def rgl_eval(tables: RglTables, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
    """An RGL measured BRDF (`neumat.reflectance.measured.RglMaterial.eval`) of float32 directions (N, 3): (N, 3),
    0 unless both are above the surface."""
    lib = library()
    wi, wo = wi.contiguous(), wo.contiguous()
    out = torch.empty(len(wi), 3)
    fn = lib.rgl_eval
    t = tables

    def run(start: int, stop: int) -> None:
        _check(fn(_ptr(wi, start), _ptr(wo, start), ctypes.c_long(stop - start), int(t.isotropic), t.reduction,
                  int(t.jacobian), _ptr(t.phi), len(t.phi), _ptr(t.theta), len(t.theta), ctypes.byref(t.vndf),
                  ctypes.byref(t.rgb), ctypes.byref(t.ndf), ctypes.byref(t.sigma), _ptr(out, start)))
    by_threads(run, len(wi))
    return out


def sparse_btf_fits(neighbours: int, patch: int, n_light: int, n_view: int) -> bool:
    """Whether `sparse_btf_eval`'s buffers hold a SparseBTF of these sizes, as its C checks; a larger one keeps its
    torch path."""
    return 1 <= neighbours <= 8 and patch <= 32 and n_light <= 4096 and n_view <= 4096


def sparse_btf_eval(model, wi: torch.Tensor, wo: torch.Tensor, uv: torch.Tensor, yuv_rgb: torch.Tensor) -> torch.Tensor:
    """A SparseBTF (`neumat.methods.sparse_btf.model.SparseBTF`, angular interpolation in coefficient space) of
    float32 directions wi, wo (N, 3) and uv (N, 2): (N, 3), 0 unless both directions are above the surface.
    yuv_rgb: the 3 x 3 matrix from the model's YUV to linear RGB."""
    lib = library()
    t = prepared(model, lambda: _sparse_btf_tables(model, yuv_rgb))
    c = model.cfg
    wi, wo, uv = wi.contiguous(), wo.contiguous(), uv.contiguous()
    out = torch.empty(len(wi), 3)
    fn = lib.sparse_btf_eval

    def run(start: int, stop: int) -> None:
        _check(fn(_ptr(wi, start), _ptr(wo, start), _ptr(uv, start), ctypes.c_long(stop - start), t.light, c.n_light,
                  t.view, c.n_view, c.neighbours, c.height, c.width, c.patch, c.num_dictionaries, t.T, *t.codes,
                  *t.dicts, t.mean, t.std, t.yuv_rgb, ctypes.c_float(c.log_eps), _ptr(out, start)))
    by_threads(run, len(wi))
    return out


def _sparse_btf_tables(model, yuv_rgb: torch.Tensor) -> SimpleNamespace:
    """What `sparse_btf_eval` reads: the model's tables contiguous (the direction sets transposed, 3 x count) and
    their pointers."""
    keep = {name: on_huge_pages(getattr(model, name)) for name in (
        "membership", "counts", "values", "index", "dict_1", "dict_2", "dict_3", "dict_4", "mean", "std")}
    keep.update(light=model.light_dirs.t().contiguous(), view=model.view_dirs.t().contiguous(),
                yuv_rgb=yuv_rgb.float().contiguous())
    ptr = {name: _ptr(v) for name, v in keep.items()}
    return SimpleNamespace(keep=keep, T=keep["values"].shape[-1], light=ptr["light"], view=ptr["view"],
                           codes=[ptr[n] for n in ("membership", "counts", "values", "index")],
                           dicts=[ptr[f"dict_{i}"] for i in range(1, 5)], mean=ptr["mean"], std=ptr["std"],
                           yuv_rgb=ptr["yuv_rgb"])


def pca_btf_eval(model, wi: torch.Tensor, wo: torch.Tensor, uv: torch.Tensor, yuv_rgb: torch.Tensor) -> torch.Tensor:
    """A PCA-compressed BTF (`neumat.methods.sparse_btf.pca.PCABTF`) of float32 directions wi, wo (N, 3) and uv
    (N, 2): (N, 3), 0 unless both directions are above the surface. yuv_rgb: the 3 x 3 matrix from the model's YUV
    to linear RGB."""
    lib = library()
    t = prepared(model, lambda: _pca_btf_tables(model, yuv_rgb))
    c = model.cfg
    wi, wo, uv = wi.contiguous(), wo.contiguous(), uv.contiguous()
    out = torch.empty(len(wi), 3)
    fn = lib.pca_btf_eval

    def run(start: int, stop: int) -> None:
        _check(fn(_ptr(wi, start), _ptr(wo, start), _ptr(uv, start), ctypes.c_long(stop - start), t.light, c.n_light,
                  t.view, c.n_view, c.neighbours, c.height, c.width, t.R, t.coeffs, t.basis, t.mean,
                  t.yuv_rgb, ctypes.c_float(c.log_eps), _ptr(out, start)))
    by_threads(run, len(wi))
    return out


def _pca_btf_tables(model, yuv_rgb: torch.Tensor) -> SimpleNamespace:
    """What `pca_btf_eval` reads: the model's tables contiguous (the direction sets transposed, 3 x count) and their
    pointers."""
    keep = {"coeffs": on_huge_pages(model.coeffs), "basis": on_huge_pages(model.basis),
            "mean": model.mean.contiguous(), "light": model.light_dirs.t().contiguous(),
            "view": model.view_dirs.t().contiguous(), "yuv_rgb": yuv_rgb.float().contiguous()}
    return SimpleNamespace(keep=keep, R=keep["basis"].shape[-1], **{name: _ptr(v) for name, v in keep.items()})


def mlp_forward(mlp: PackedMLP, x: torch.Tensor) -> torch.Tensor:
    """The packed MLP of float32 rows x (N, in): (N, out_dim) (the block MLP every kernel ends in, alone: tests
    hold it against torch at any width and activation)."""
    lib = library()
    x = x.contiguous()
    out = torch.empty(len(x), mlp.out_dim)
    fn = lib.mlp_forward

    def run(start: int, stop: int) -> None:
        _check(fn(_ptr(x, start), ctypes.c_long(stop - start), mlp.layers, mlp.dims, mlp.w, mlp.b, mlp.hidden_act,
                  mlp.out_dim, _ptr(out, start)))
    by_threads(run, len(x))
    return out


def ring_pixels(nside: int, xyz: torch.Tensor, exact_atan2: bool = False) -> torch.Tensor:
    """The kernels' HEALPix ring pixels (N,) int32 of float32 unit vectors (N, 3), or with `exact_atan2` with libm's
    atan2f on every row instead of the vectorised one and its checked fallback (tests)."""
    xyz = xyz.float().contiguous()
    out = torch.empty(len(xyz), dtype=torch.int32)
    library().ring_pixels_of(_ptr(xyz), ctypes.c_long(len(xyz)), nside, int(exact_atan2), _ptr(out))
    return out


def healpix_corner_vertices(nside: int, pix: torch.Tensor, level: torch.Tensor | int) -> torch.Tensor:
    """`neumat.nn.healpix._corner_vertices`: the corner vertex ids (..., 4) int64 of the level-`level` ancestors (an
    int, or a tensor broadcast against pix) of ring pixels pix (...) int64, bit for bit."""
    shape = pix.shape
    pix = pix.to(torch.int64).reshape(-1).contiguous()
    per_pixel = isinstance(level, torch.Tensor) and level.dim() > 0
    if per_pixel:
        level = level.to(torch.int64).expand(shape).reshape(-1).contiguous()
    out = torch.empty(len(pix), 4, dtype=torch.int64)
    library().healpix_corner_vertices(ctypes.c_long(nside), _ptr(pix), _ptr(level) if per_pixel else None,
                                      0 if per_pixel else int(level), ctypes.c_long(len(pix)), _ptr(out))
    return out.view(*shape, 4)  # not counted in `calls` (a lookup's geometry, not a model's evaluation)


def exp_values(x: torch.Tensor, minus_one: bool) -> torch.Tensor:
    """The kernels' exp (or expm1) of float32 values (tests)."""
    x = x.float().contiguous()
    out = torch.empty_like(x)
    library().exp_values(_ptr(x), ctypes.c_long(x.numel()), int(minus_one), _ptr(out))
    return out
