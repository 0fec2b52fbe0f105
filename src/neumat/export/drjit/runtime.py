"""The Dr.Jit runtime of exported models: load a `drjit` export and evaluate it on Dr.Jit arrays, without torch.

An export (`neumat.export.drjit.format`, `neumat export --format drjit`) is a folder holding `manifest.json` (the
program and its settings) and `arrays.npz` (the weights, stored as the method's translator wrote them: fp16 where
the runtime form rounded them to fp16). `load_runtime(path, backend)` reads it with numpy only and builds a
`Runtime` whose `eval(wi, wo, active)` is pure Dr.Jit, so it records in symbolic (megakernel) mode and runs on the
LLVM and CUDA backends alike. This module imports neither torch nor any torch-using part of neumat.

Programs (the manifest's "program"; one per model family's runtime form, `PROGRAMS`):

- "healpix-mlp" (NeuBRDF): the runtime form of `neumat.methods.neubrdf.model.NeuBRDF` with uniform corner weights:
  the ring pixels of wi and wo (`vec2pix`), two rows of the per-pixel first-layer table (built at load from the
  corner features and the first MLP layer), the direction inputs' first-layer columns, the rest of the MLP
  (`Mlp`: `drjit.nn` cooperative vectors) and exp.

Shared pieces a new program uses: `vec2pix` (HEALPix ring pixel, float32 as `neumat.nn.healpix.vec2pix_xyz`),
`direction_inputs` (NBRDF's half / difference vectors, optionally warped), `Mlp`.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ...core.errors import DataFormatError, InputError

FORMAT = "neumat-drjit"
FORMAT_VERSION = 1
MANIFEST = "manifest.json"
ARRAYS = "arrays.npz"
#: compute precisions: "fp32" (the default on LLVM, where fp16 measured 2x slower) and "fp16" (the default on CUDA)
COMPUTE = ("fp32", "fp16")


# ------------------------------------------------------------------------------------------------ files

def write_export(folder: str | Path, manifest: dict, arrays: dict[str, np.ndarray]) -> Path:
    """Write `manifest` (JSON) and `arrays` (numpy) to `folder` (created); returns the folder."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    np.savez(folder / ARRAYS, **arrays)
    (folder / MANIFEST).write_text(json.dumps(manifest, indent=1, allow_nan=False) + "\n")
    return folder


def is_export(path: str | Path) -> bool:
    """Whether `path` is a drjit export: a folder holding a manifest.json, or such a manifest.json."""
    p = Path(path)
    return (p / MANIFEST).is_file() or (p.name == MANIFEST and p.is_file())


def read_export(path: str | Path) -> tuple[dict, dict[str, np.ndarray]]:
    """(manifest, arrays) of the drjit export at `path` (its folder or its manifest.json); DataFormatError naming
    the file when it is not one this version reads."""
    p = Path(path)
    folder = p.parent if p.name == MANIFEST else p
    where = str(folder / MANIFEST)
    try:
        manifest = json.loads((folder / MANIFEST).read_text())
    except FileNotFoundError:
        raise InputError(f"drjit export {str(folder)!r}: no {MANIFEST} (write one with `neumat export --format "
                         "drjit`)") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise DataFormatError(f"{where}: not JSON ({e})") from None
    if not isinstance(manifest, dict) or manifest.get("format") != FORMAT:
        raise DataFormatError(f"{where}: expected format {FORMAT!r}")
    if not isinstance(manifest.get("format_version"), int) or manifest["format_version"] > FORMAT_VERSION:
        raise DataFormatError(f"{where}: format version {manifest.get('format_version')!r}; this neumat reads "
                              f"versions up to {FORMAT_VERSION}")
    if manifest.get("program") not in PROGRAMS:
        raise DataFormatError(f"{where}: unknown program {manifest.get('program')!r} (known: {', '.join(PROGRAMS)})")
    try:
        with np.load(folder / ARRAYS, allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
    except (OSError, ValueError) as e:
        raise DataFormatError(f"{folder / ARRAYS}: cannot read the arrays ({e})") from None
    return manifest, arrays


# --------------------------------------------------------------------------------------------- backends

@dataclass(frozen=True)
class Backend:
    """The Dr.Jit array types of one backend (a module such as drjit.llvm.ad or drjit.cuda.ad)."""

    module: Any

    @property
    def Float(self):
        return self.module.Float

    @property
    def Float16(self):
        return self.module.Float16

    @property
    def Int(self):
        return self.module.Int

    @property
    def UInt(self):
        return self.module.UInt

    @property
    def Bool(self):
        return self.module.Bool

    @property
    def ArrayXf(self):
        return self.module.ArrayXf

    @property
    def Array3f(self):
        return self.module.Array3f

    @property
    def TensorXf(self):
        return self.module.TensorXf

    @property
    def TensorXf16(self):
        return self.module.TensorXf16

    @property
    def is_cuda(self) -> bool:
        return ".cuda" in self.module.__name__


def backend_of(spec) -> Backend:
    """The Backend named by `spec`: "llvm", "cuda", a Dr.Jit array module, or a Dr.Jit Float type (e.g.
    `mitsuba.Float`, whose module is the variant's)."""
    import importlib

    if isinstance(spec, Backend):
        return spec
    if spec in ("llvm", "cuda"):
        return Backend(importlib.import_module(f"drjit.{spec}.ad"))
    if isinstance(spec, type):
        return Backend(importlib.import_module(spec.__module__))
    if hasattr(spec, "Float") and hasattr(spec, "TensorXf"):
        return Backend(spec)
    raise InputError(f"backend: expected 'llvm', 'cuda', a Dr.Jit array module or Float type, got {spec!r}")


# ------------------------------------------------------------------------------------------- shared pieces

def vec2pix(b: Backend, nside: int, x, y, z):
    """HEALPix ring pixel (Int) of unit vectors (x, y, z) (Floats), the float32 operations of
    `neumat.nn.healpix.vec2pix_xyz` (healpy loc2pix; the polar caps use the sin(theta) form)."""
    import drjit as dr

    n = nside
    Int = b.Int
    tt = dr.atan2(y, x) * (2 / math.pi)
    tt = dr.select(tt < 0, tt + 4, tt)
    tt = dr.select(tt >= 4, 0.0, tt)
    z_abs = dr.abs(z)
    sth = dr.sqrt(x * x + y * y)
    # equatorial belt
    temp1 = tt * n + 0.5 * n
    temp2 = z * (0.75 * n)
    jp = Int(temp1 - temp2)
    jm = Int(temp1 + temp2)
    ir = jp - jm + (n + 1)
    kshift = 1 - (ir & 1)
    t = (jp + jm + kshift + (1 - n)) >> 1
    t = t - (t // (4 * n)) * (4 * n)  # C's remainder (truncating division) ...
    t = dr.select(t < 0, t + 4 * n, t)  # ... made torch's (non-negative)
    pix_eq = t + (ir - 1) * (4 * n) + 2 * n * (n - 1)
    # polar caps
    tp = tt - dr.trunc(tt)
    tmp = sth * n / dr.sqrt((z_abs + 1) * (1 / 3))
    jp = Int(tp * tmp)
    jm = Int((1 - tp) * tmp)
    ir = jp + jm + 1
    ip = dr.minimum(Int(tt * b.Float(ir)), 4 * ir - 1)
    north = (ir - 1) * (2 * ir) + ip
    south = (12 * n * n) - (ir + 1) * (2 * ir) + ip
    return dr.select(z_abs <= 2 / 3, pix_eq, dr.select(z > 0, north, south))


def direction_inputs(kind: str, wi, wo) -> list:
    """The 6 extra MLP inputs of NeuBRDF's `Config.direction_inputs` `kind` ("hd" or "hd_warp") as Floats:
    NBRDF's half vector h and difference vector d (wi in the frame whose pole is h); "hd_warp" rescales (h.x, h.y)
    to length sqrt(theta_h / (pi / 2)) (`neumat.methods.neubrdf.model.direction_inputs`)."""
    import drjit as dr

    hx, hy, hz = wi[0] + wo[0], wi[1] + wo[1], wi[2] + wo[2]
    inv = 1 / dr.maximum(dr.sqrt(hx * hx + hy * hy + hz * hz), 1e-12)
    hx, hy, hz = hx * inv, hy * inv, hz * inv
    st = dr.sqrt(hx * hx + hy * hy)
    has = st > 0
    inv_st = 1 / dr.select(has, st, 1.0)
    cp = dr.select(has, hx * inv_st, 1.0)
    sp = dr.select(has, hy * inv_st, 0.0)
    a = cp * wi[0] + sp * wi[1]
    d = [hz * a - st * wi[2], cp * wi[1] - sp * wi[0], st * a + hz * wi[2]]
    if kind == "hd_warp":
        r = dr.sqrt(dr.atan2(st, hz) * (2 / math.pi))
        return [dr.select(has, cp * r, 0.0), dr.select(has, sp * r, 0.0), hz, *d]
    return [hx, hy, hz, *d]


def _activation(name: str) -> Callable:
    import drjit as dr

    if name == "relu":
        return lambda x: dr.maximum(x, 0.0)
    if name == "leaky_relu":  # torch's slope 0.01; max(x, 0.01 x) is x for x >= 0 and 0.01 x below
        return lambda x: dr.maximum(x, 0.01 * x)
    if name == "tanh":
        return dr.tanh
    raise InputError(f"drjit runtime: activation {name!r} has no Dr.Jit form (supported: relu, leaky_relu, tanh)")


class Mlp:
    """Linear layers with an activation between them, as `drjit.nn` cooperative-vector products
    (`drjit.nn.matvec`; on CUDA these use tensor cores). weights: [(W (out, in), b (out,) or None), ...] numpy;
    compute "fp32" or "fp16" (weights and arithmetic at that precision). `__call__(x)`: x a list of Floats (or a
    CoopVec) -> the output CoopVec before any output activation. Measured on LLVM, one thread: 3.8e6
    evaluations/s of NeuBRDF's 64-64-3 tail in fp32 against 1.0e6 for the same products unrolled as dr.fma."""

    def __init__(self, b: Backend, weights: list, activation: str, compute: str = "fp32") -> None:
        import drjit.nn as nn

        if compute not in COMPUTE:
            raise InputError(f"drjit runtime compute: expected one of {', '.join(COMPUTE)}, got {compute!r}")
        self.backend, self.compute = b, compute
        tensor = b.TensorXf16 if compute == "fp16" else b.TensorXf
        items = []
        for w, bias in weights:
            items.append(tensor(np.ascontiguousarray(w, dtype=np.float32)))
            items.append(None if bias is None else tensor(np.ascontiguousarray(bias, dtype=np.float32)))
        present = [t for t in items if t is not None]
        packed = nn.pack(*present, layout="inference")
        it = iter((packed,) if len(present) == 1 else packed)  # one matrix packs to a view, several to a tuple
        self.layers = [(next(it), None if items[2 * i + 1] is None else next(it)) for i in range(len(weights))]
        self.act = _activation(activation)

    def vec(self, values):
        """A CoopVec of `values` (Floats) at the compute precision."""
        import drjit.nn as nn

        if self.compute == "fp16":
            return nn.CoopVec([self.backend.Float16(v) for v in values])
        return nn.CoopVec(values)

    def __call__(self, x, first_activation: bool = False):
        import drjit.nn as nn

        if not isinstance(x, nn.CoopVec):
            x = self.vec(x)
        for i, (w, bias) in enumerate(self.layers):
            if i or first_activation:
                x = self.act(x)
            x = nn.matvec(w, x, bias)
        return x

    def floats(self, x) -> list:
        """The components of CoopVec x as Floats (fp32)."""
        return [self.backend.Float(v) for v in x]


# ------------------------------------------------------------------------------------------------ programs

class Runtime:
    """An exported model on Dr.Jit arrays. `eval(wi, wo, active)` -> Array3f: the BRDF value (linear RGB, cosine
    excluded) for directions wi, wo (Array3f, local frame, z the normal), 0 below the horizon and on inactive
    lanes. Attributes: manifest, spatially_varying, can_sample (False: callers sample cosine-weighted)."""

    spatially_varying = False
    can_sample = False

    def __init__(self, manifest: dict, backend: Backend, compute: str) -> None:
        self.manifest, self.backend, self.compute = manifest, backend, compute

    def describe(self) -> str:
        return str(self.manifest.get("describe", self.manifest.get("model", "?")))

    def eval(self, wi, wo, active=True):  # pragma: no cover - programs define it
        raise NotImplementedError


class HealpixMlp(Runtime):
    """Program "healpix-mlp": NeuBRDF's runtime form (module docstring). Arrays: features (R, k), pixel_rows
    (2, 12 nside^2, 4) (feature rows of each pixel's 4 corners on S+ by the pixel of wi, on S- by the pixel of the
    unmirrored wo; -1: none), first_weight (hidden, 2 k + extra), first_bias (hidden,), then layer{i}_weight /
    layer{i}_bias for the layers after the first."""

    def __init__(self, manifest: dict, arrays: dict, backend: Backend, compute: str) -> None:
        super().__init__(manifest, backend, compute)
        import drjit as dr

        b = backend
        self.nside = n = int(manifest["nside"])
        k, hidden = int(manifest["feature_dim"]), int(manifest["hidden"])
        self.kind = manifest.get("direction_inputs", "none")
        extra = {"none": 0, "hd": 6, "hd_warp": 6}[self.kind]
        feats = arrays["features"].astype(np.float32)
        rows = arrays["pixel_rows"].astype(np.int64)
        w1 = arrays["first_weight"].astype(np.float32)
        if rows.shape != (2, 12 * n * n, 4) or feats.shape[1] != k or w1.shape != (hidden, 2 * k + extra):
            raise DataFormatError(f"drjit export ({self.describe()}): array shapes do not match the manifest")
        # per-pixel mean corner features (0 for pixels outside the hemisphere, never looked up), then the first
        # layer's pre-activations: wi's pixel with the bias, wo's pixel (the sum is the first layer's output)
        padded = np.concatenate([feats, np.zeros((1, k), np.float32)])
        mean = padded[np.where(rows < 0, len(feats), rows)].mean(2, dtype=np.float32)
        mean[(rows < 0).any(-1)] = 0.0
        table = np.concatenate([mean[0] @ w1[:, :k].T + arrays["first_bias"].astype(np.float32),
                                mean[1] @ w1[:, k:2 * k].T]).astype(np.float32)
        self.hidden, self.pixels = hidden, 12 * n * n
        self.table = b.Float(np.ascontiguousarray(table).ravel())
        layers = []
        i = 1
        while f"layer{i}_weight" in arrays:
            layers.append((arrays[f"layer{i}_weight"], arrays[f"layer{i}_bias"]))
            i += 1
        self.mlp = Mlp(b, layers, manifest["activation"], compute)
        self.hd = Mlp(b, [(w1[:, 2 * k:], None)], manifest["activation"], compute) if extra else None
        self.output = manifest.get("output", "exp")
        dr.eval(self.table)

    def eval(self, wi, wo, active=True):
        import drjit as dr

        b = self.backend
        active = b.Bool(active) & (wi[2] > 0) & (wo[2] > 0)
        pi = vec2pix(b, self.nside, wi[0], wi[1], wi[2])
        po = vec2pix(b, self.nside, wo[0], wo[1], wo[2]) + self.pixels
        ok = active & (pi >= 0) & (pi < self.pixels) & (po >= self.pixels) & (po < 2 * self.pixels)
        # two table rows per lane, each one packet gather of `hidden` contiguous floats (2x faster on LLVM than
        # `hidden` scalar gathers)
        n = dr.width((pi, po, ok))
        rows = [dr.gather(b.ArrayXf, self.table, b.UInt(p), ok, shape=(self.hidden, n)) for p in (pi, po)]
        h = [rows[0][j] + rows[1][j] for j in range(self.hidden)]
        x = self.mlp.vec(h)
        if self.hd is not None:
            x = x + self.hd(direction_inputs(self.kind, wi, wo))
        out = self.mlp.floats(self.mlp(x, first_activation=True))
        if self.output == "exp":
            out = [dr.exp(v) for v in out]
        return dr.select(ok, b.Array3f(*out), 0.0)


#: program name -> its Runtime class (constructor (manifest, arrays, backend, compute))
PROGRAMS: dict[str, type] = {"healpix-mlp": HealpixMlp}


def load_runtime(source, backend="llvm", compute: str | None = None) -> Runtime:
    """The Runtime of a drjit export. source: the export's folder or manifest.json, or (manifest, arrays) as a
    translator returns them; backend: see `backend_of` (e.g. `mitsuba.Float` for the current variant's);
    compute: "fp32" or "fp16" (default: fp16 on CUDA, fp32 on LLVM)."""
    manifest, arrays = source if isinstance(source, tuple) else read_export(source)
    b = backend_of(backend)
    if compute is None:
        compute = "fp16" if b.is_cuda else "fp32"
    if compute not in COMPUTE:
        raise InputError(f"drjit runtime compute: expected one of {', '.join(COMPUTE)}, got {compute!r}")
    if manifest.get("program") not in PROGRAMS:
        raise DataFormatError(f"drjit export: unknown program {manifest.get('program')!r}")
    return PROGRAMS[manifest["program"]](manifest, arrays, b, compute)
