"""The Dr.Jit runtime of exported models: load a `drjit` export and evaluate it on Dr.Jit arrays, without torch.

An export (`neumat export --format drjit`) is a folder holding `manifest.json` (the program and its settings) and
`arrays.npz` (the weights). `load_runtime(path, backend)` reads it with numpy only and builds a `Runtime` whose
`eval(wi, wo, active)` is pure Dr.Jit (symbolic mode, LLVM and CUDA alike). One program per model family's runtime
form (`PROGRAMS`); shared pieces `vec2pix`, `direction_inputs`, `Mlp`. Programs and formats: docs/formats/drjit.md.
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
    if manifest.get("program") not in programs():
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

    #: the array types programs use, read from `module` (`backend.Float` is `module.Float`)
    TYPES = ("Float", "Float16", "Int", "UInt", "Bool", "ArrayXf", "Array3f", "TensorXf", "TensorXf16")

    def __getattr__(self, name: str):
        if name in Backend.TYPES:
            return getattr(self.module, name)
        raise AttributeError(f"{type(self).__name__} has no attribute {name!r}")

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

    h, d = hd_vectors(wi, wo)
    if kind == "hd_warp":
        hx, hy, hz = h
        st = dr.sqrt(hx * hx + hy * hy)
        has = st > 0
        scale = dr.sqrt(dr.atan2(st, hz) * (2 / math.pi)) / dr.select(has, st, 1.0)
        return [dr.select(has, hx * scale, 0.0), dr.select(has, hy * scale, 0.0), hz, *d]
    return [*h, *d]


def _activation(name: str) -> Callable:
    import drjit as dr

    if name == "relu":
        return lambda x: dr.maximum(x, 0.0)
    if name == "leaky_relu":  # torch's slope 0.01; max(x, 0.01 x) is x for x >= 0 and 0.01 x below
        return lambda x: dr.maximum(x, 0.01 * x)
    if name == "tanh":
        return dr.tanh
    if name == "silu":  # x sigmoid(x) = x (1 + tanh(x / 2)) / 2: tanh, products and sums, which cooperative
        return lambda x: (0.5 * x) * (1.0 + dr.tanh(0.5 * x))  # vectors support (they have no negation or exp)
    raise InputError(f"drjit runtime: activation {name!r} has no Dr.Jit form (supported: {', '.join(ACTIVATIONS)})")


#: hidden activations with a Dr.Jit form
ACTIVATIONS = ("relu", "leaky_relu", "tanh", "silu")


#: MLP forms: "literal" (weights as constants of the kernel, unrolled dr.fma; the default at fp32) and "coopvec"
#: (`drjit.nn` cooperative-vector products on packed weight buffers; the default at fp16, on tensor cores under
#: CUDA, whose packed layouts take half precision only). Measured on LLVM (one thread, NeuBRDF's 64-64-3 tail, 2^18
#: queries): literal 0.075 s, coopvec 0.090 s in a plain kernel; inside a symbolic call (Mitsuba's megakernel mode,
#: `dr.switch`) literal 0.052 s, coopvec 0.549 s: there every weight of a packed buffer is read per lane.
FORMS = ("literal", "coopvec")


class Mlp:
    """Linear layers with an activation between them. weights: [(W (out, in), b (out,) or None), ...] numpy;
    compute "fp32" or "fp16"; form (`FORMS`): "literal" (fp32 only: the weights become constants of the kernel,
    each output an unrolled chain of dr.fma; Dr.Jit's LLVM backend compiles it into broadcast constants) or
    "coopvec" (`drjit.nn.matvec` on packed buffers at the compute precision; fp16 only on CUDA). Default: literal
    for fp32, coopvec for fp16. `__call__(x, first_activation)`: x a list of Floats -> the outputs (fp32 Floats)
    before any output activation."""

    def __init__(self, b: Backend, weights: list, activation: str, compute: str = "fp32",
                 form: str | None = None) -> None:
        if compute not in COMPUTE:
            raise InputError(f"drjit runtime compute: expected one of {', '.join(COMPUTE)}, got {compute!r}")
        if form is None:
            form = "literal" if compute == "fp32" else "coopvec"
        if form == "coopvec" and compute == "fp32" and b.is_cuda:  # nn.pack's layouts need OptiX's conversion
            raise InputError("drjit runtime: cooperative vectors on CUDA take half precision only (Dr.Jit's packed "
                             "layouts); use compute fp16, or the literal form for fp32")
        if form not in FORMS or (form == "literal" and compute != "fp32"):
            raise InputError(f"drjit runtime MLP form: expected one of {', '.join(FORMS)} (literal for fp32 only), "
                             f"got {form!r} with compute {compute!r}")
        self.backend, self.compute, self.form = b, compute, form
        self.act = _activation(activation)
        self.sizes = [np.shape(w) for w, _ in weights]
        if form == "literal":
            self.weights = [(np.asarray(w, np.float32).tolist(),
                             None if bias is None else np.asarray(bias, np.float32).tolist()) for w, bias in weights]
            return
        import drjit.nn as nn

        tensor = b.TensorXf16 if compute == "fp16" else b.TensorXf
        items = []
        for w, bias in weights:
            items.append(tensor(np.ascontiguousarray(w, dtype=np.float32)))
            items.append(None if bias is None else tensor(np.ascontiguousarray(bias, dtype=np.float32)))
        present = [t for t in items if t is not None]
        packed = nn.pack(*present, layout="inference")
        it = iter((packed,) if len(present) == 1 else packed)  # one matrix packs to a view, several to a tuple
        self.layers = [(next(it), None if items[2 * i + 1] is None else next(it)) for i in range(len(weights))]

    def __call__(self, x, first_activation: bool = False) -> list:
        if self.form == "literal":
            return self._literal(list(x), first_activation)
        import drjit.nn as nn

        b = self.backend
        x = nn.CoopVec([b.Float16(v) for v in x] if self.compute == "fp16" else list(x))
        for i, (w, bias) in enumerate(self.layers):
            if i or first_activation:
                x = self.act(x)
            x = nn.matvec(w, x, bias)
        return [b.Float(v) for v in x]

    def _literal(self, x: list, first_activation: bool) -> list:
        import drjit as dr

        Float = self.backend.Float
        for i, (w, bias) in enumerate(self.weights):
            if i or first_activation:
                x = [self.act(v) for v in x]
            out = []
            for o, row in enumerate(w):
                acc = None if bias is None else Float(bias[o])
                for v, c in zip(x, row):
                    if c == 0.0:
                        continue
                    acc = v * c if acc is None else dr.fma(v, c, acc)
                out.append(Float(0.0) if acc is None else acc)
            x = out
        return x


# ------------------------------------------------------------------------------------------------ programs

class Runtime:
    """An exported model on Dr.Jit arrays. `eval(wi, wo, active, uv, footprint)` -> Array3f: the BRDF value
    (linear RGB, cosine excluded) for directions wi, wo (Array3f, local frame, z the normal), 0 below the horizon
    and on inactive lanes; uv (two Floats) and footprint (the covariance in uv^2 as three Floats (s_uu, s_uv,
    s_vv), None: the finest level) are read by spatially varying programs only. Attributes: manifest,
    spatially_varying, can_sample (False: callers sample cosine-weighted; True: `sample(wi, u0, u1, active)` ->
    (wo Array3f, pdf Float) and `pdf(wi, wo, active)` -> Float, the model's own sampler)."""

    spatially_varying = False
    can_sample = False

    def __init__(self, manifest: dict, backend: Backend, compute: str, mlp_form: str | None = None) -> None:
        self.manifest, self.backend, self.compute, self.mlp_form = manifest, backend, compute, mlp_form

    def describe(self) -> str:
        return str(self.manifest.get("describe", self.manifest.get("model", "?")))

    def eval(self, wi, wo, active=True, uv=None, footprint=None):  # pragma: no cover - programs define it
        raise NotImplementedError


class HealpixMlp(Runtime):
    """Program "healpix-mlp": NeuBRDF's runtime form (module docstring). Arrays: features (R, k), pixel_rows
    (2, 12 nside^2, 4) (feature rows of each pixel's 4 corners on S+ by the pixel of wi, on S- by the pixel of the
    unmirrored wo; -1: none), first_weight (hidden, 2 k + extra), first_bias (hidden,), then layer{i}_weight /
    layer{i}_bias for the layers after the first."""

    def __init__(self, manifest: dict, arrays: dict, backend: Backend, compute: str,
                 mlp_form: str | None = None) -> None:
        super().__init__(manifest, backend, compute, mlp_form)
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
        self.mlp = Mlp(b, layers, manifest["activation"], compute, mlp_form)
        self.hd = Mlp(b, [(w1[:, 2 * k:], None)], manifest["activation"], compute, mlp_form) if extra else None
        self.output = manifest.get("output", "exp")
        dr.eval(self.table)

    def eval(self, wi, wo, active=True, uv=None, footprint=None):
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
        if self.hd is not None:
            h = [a + c for a, c in zip(h, self.hd(direction_inputs(self.kind, wi, wo)))]
        out = self.mlp(h, first_activation=True)
        if self.output == "exp":
            out = [dr.exp(v) for v in out]
        return dr.select(ok, b.Array3f(*out), 0.0)


def mlp_layers(arrays: dict, prefix: str = "layer", first: int = 0) -> list:
    """[(W, b), ...] of the arrays {prefix}{i}_weight / {prefix}{i}_bias, i = first, first + 1, ..."""
    layers, i = [], first
    while f"{prefix}{i}_weight" in arrays:
        layers.append((arrays[f"{prefix}{i}_weight"], arrays[f"{prefix}{i}_bias"]))
        i += 1
    return layers


def hd_vectors(wi, wo):
    """Rusinkiewicz half vector h and difference vector d (lists of 3 Floats) of wi, wo, as
    `neumat.core.coords.io_to_hd` (phi_h = 0 at the pole)."""
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
    return [hx, hy, hz], [hz * a - st * wi[2], cp * wi[1] - sp * wi[0], st * a + hz * wi[2]]


class DirectionMlp(Runtime):
    """Program "direction-mlp" (NBRDF, the naive MLP): out(MLP(inputs(wi, wo))). Manifest: inputs "wiwo" (the
    two directions concatenated) or "hd" (NBRDF's half / difference vectors; half "vector" or "theta"
    ((sin theta_h, 0, cos theta_h)), fold_phi_d: d mirrored to dy >= 0), activation, output "exp" or
    "exp_minus_one" (max(exp(x) - 1, 0)). Arrays: layer{i}_weight / layer{i}_bias from 0."""

    def __init__(self, manifest: dict, arrays: dict, backend: Backend, compute: str,
                 mlp_form: str | None = None) -> None:
        super().__init__(manifest, backend, compute, mlp_form)
        self.inputs = manifest["inputs"]
        self.half = manifest.get("half", "vector")
        self.fold = bool(manifest.get("fold_phi_d", False))
        self.output = manifest["output"]
        if self.inputs not in ("wiwo", "hd") or self.half not in ("vector", "theta") or \
                self.output not in ("exp", "exp_minus_one"):
            raise DataFormatError(f"drjit export ({self.describe()}): unknown inputs / half / output")
        layers = mlp_layers(arrays)
        if not layers or np.shape(layers[0][0])[1] != 6 or np.shape(layers[-1][0])[0] != 3:
            raise DataFormatError(f"drjit export ({self.describe()}): expected an MLP 6 -> ... -> 3")
        self.mlp = Mlp(backend, layers, manifest["activation"], compute, mlp_form)

    def eval(self, wi, wo, active=True, uv=None, footprint=None):
        import drjit as dr

        b = self.backend
        ok = b.Bool(active) & (wi[2] > 0) & (wo[2] > 0)
        if self.inputs == "wiwo":
            x = [wi[0], wi[1], wi[2], wo[0], wo[1], wo[2]]
        else:
            h, d = hd_vectors(wi, wo)
            if self.half == "theta":
                h = [dr.sqrt(h[0] * h[0] + h[1] * h[1]), b.Float(0.0), h[2]]
            if self.fold:
                flip = d[1] < 0
                d = [dr.select(flip, -d[0], d[0]), dr.select(flip, -d[1], d[1]), d[2]]
            x = [*h, *d]
        out = self.mlp(x)
        if self.output == "exp_minus_one":
            out = [dr.maximum(expm1(v), 0.0) for v in out]
        else:
            out = [dr.exp(v) for v in out]
        return dr.select(ok, b.Array3f(*out), 0.0)


def expm1(x):
    """exp(x) - 1 without the cancellation of the plain difference near 0 (an NBRDF's dark values lost all but a
    few bits there: 1e-7 absolute on values of 1e-4), Kahan's form: (u - 1) x / log(u), u = exp(x)."""
    import drjit as dr

    u = dr.exp(x)
    um1 = u - 1
    return dr.select(um1 == 0, x, dr.select(um1 == -1, -1.0, um1 * x / dr.log(u)))


class Ggx(Runtime):
    """Program "ggx" (the fitted GGX, `neumat.methods.baselines.ggx.GGXFit`): diffuse / pi + D G1 G1 F_schlick /
    (4 cos_i cos_o), and its sampler: with probability p_diffuse cosine-weighted (the concentric-disk warp),
    otherwise wi mirrored about a GGX visible normal (Heitz 2018); u0 picks the lobe and is rescaled, as
    `GGXFit.sample`. Manifest: diffuse (3), specular (3, Schlick F0), alpha (alpha_x, alpha_y), p_diffuse."""

    can_sample = True

    def __init__(self, manifest: dict, arrays: dict, backend: Backend, compute: str,
                 mlp_form: str | None = None) -> None:
        super().__init__(manifest, backend, compute, mlp_form)
        self.diffuse = [float(v) for v in manifest["diffuse"]]
        self.f0 = [float(v) for v in manifest["specular"]]
        self.ax, self.ay = (float(v) for v in manifest["alpha"])
        self.p_d = float(manifest["p_diffuse"])
        if len(self.diffuse) != 3 or len(self.f0) != 3 or not (self.ax > 0 and self.ay > 0):
            raise DataFormatError(f"drjit export ({self.describe()}): bad GGX parameters")

    def _ndf(self, m):
        q = (m[0] / self.ax) ** 2 + (m[1] / self.ay) ** 2 + m[2] * m[2]
        import drjit as dr
        return dr.select(m[2] > 0, 1 / (math.pi * self.ax * self.ay * q * q), 0.0)

    def _g1(self, w):
        import drjit as dr
        z = dr.maximum(w[2], 0.0)
        root = dr.sqrt(w[2] * w[2] + (self.ax * w[0]) ** 2 + (self.ay * w[1]) ** 2)
        return 2 * z / dr.maximum(z + root, 1.1754944e-38)

    @staticmethod
    def _half(wi, wo):
        import drjit as dr
        h = [wi[k] + wo[k] for k in range(3)]
        inv = 1 / dr.maximum(dr.sqrt(h[0] * h[0] + h[1] * h[1] + h[2] * h[2]), 1e-12)
        return [v * inv for v in h]

    def eval(self, wi, wo, active=True, uv=None, footprint=None):
        import drjit as dr

        b = self.backend
        ok = b.Bool(active) & (wi[2] > 0) & (wo[2] > 0)
        h = self._half(wi, wo)
        denom = dr.maximum(4 * wi[2] * wo[2], 1.1754944e-38)
        s = self._ndf(h) * self._g1(wi) * self._g1(wo) / denom
        w = (1 - dr.clip(wi[0] * h[0] + wi[1] * h[1] + wi[2] * h[2], 0.0, 1.0)) ** 5
        out = [self.diffuse[c] / math.pi + (self.f0[c] + (1 - self.f0[c]) * w) * s for c in range(3)]
        return dr.select(ok, b.Array3f(*out), 0.0)

    def pdf(self, wi, wo, active=True):
        import drjit as dr

        ok = self.backend.Bool(active) & (wi[2] > 0) & (wo[2] > 0)
        h = self._half(wi, wo)
        spec = self._g1(wi) * self._ndf(h) / (4 * dr.select(ok, wi[2], 1.0))
        pdf = self.p_d * dr.maximum(wo[2], 0.0) / math.pi + (1 - self.p_d) * spec
        return dr.select(ok, pdf, 0.0)

    def sample(self, wi, u0, u1, active=True):
        import drjit as dr

        b = self.backend
        up = wi[2] > 0
        wi = [dr.select(up, wi[0], 0.0), dr.select(up, wi[1], 0.0), dr.select(up, wi[2], 1.0)]
        diffuse = u0 < self.p_d
        u0 = dr.clip(dr.select(diffuse, u0 / self.p_d, (u0 - self.p_d) / (1 - self.p_d)), 0.0, 1 - 1e-7)
        # cosine-weighted: the concentric disk lifted up (neumat.warp.hemisphere.sample_cosine_hemisphere)
        a, c = 2 * u0 - 1, 2 * u1 - 1
        first = dr.abs(a) > dr.abs(c)
        r = dr.select(first, a, c)
        phi = dr.select(first, (math.pi / 4) * c / dr.select(a == 0, 1.0, a),
                        math.pi / 2 - (math.pi / 4) * a / dr.select(c == 0, 1.0, c))
        px, py = r * dr.cos(phi), r * dr.sin(phi)
        cos_dir = [px, py, dr.sqrt(dr.maximum(1 - px * px - py * py, 0.0))]
        # GGX visible normals (neumat.warp.ggx.sample_ggx_vndf), wi mirrored about them
        vx, vy, vz = self.ax * wi[0], self.ay * wi[1], wi[2]
        inv = 1 / dr.sqrt(vx * vx + vy * vy + vz * vz)
        vx, vy, vz = vx * inv, vy * inv, vz * inv
        lensq = vx * vx + vy * vy
        has = lensq > 0
        il = dr.rsqrt(dr.select(has, lensq, 1.0))
        t1 = [dr.select(has, -vy * il, 1.0), dr.select(has, vx * il, 0.0), b.Float(0.0)]
        t2 = [vy * t1[2] - vz * t1[1], vz * t1[0] - vx * t1[2], vx * t1[1] - vy * t1[0]]
        rr = dr.sqrt(dr.maximum(u0, 0.0))
        ph = 2 * math.pi * u1
        p1, p2 = rr * dr.cos(ph), rr * dr.sin(ph)
        s = 0.5 * (1 + vz)
        p2 = (1 - s) * dr.sqrt(dr.maximum(1 - p1 * p1, 0.0)) + s * p2
        p3 = dr.sqrt(dr.maximum(1 - p1 * p1 - p2 * p2, 0.0))
        nh = [p1 * t1[k] + p2 * t2[k] + p3 * v for k, v in enumerate((vx, vy, vz))]
        m = [self.ax * nh[0], self.ay * nh[1], dr.maximum(nh[2], 0.0)]
        im = 1 / dr.sqrt(m[0] * m[0] + m[1] * m[1] + m[2] * m[2])
        m = [v * im for v in m]
        dot = wi[0] * m[0] + wi[1] * m[1] + wi[2] * m[2]
        spec_dir = [2 * dot * m[k] - wi[k] for k in range(3)]
        wo = [dr.select(diffuse, cos_dir[k], spec_dir[k]) for k in range(3)]
        inv = 1 / dr.sqrt(wo[0] * wo[0] + wo[1] * wo[1] + wo[2] * wo[2])
        wo = b.Array3f(*(v * inv for v in wo))
        ok = b.Bool(active) & up & (wo[2] > 0)
        return wo, dr.select(ok, self.pdf(wi, wo, ok), 0.0)


#: program name -> its Runtime class (constructor (manifest, arrays, backend, compute, mlp_form)); more programs
#: register from `neumat.export.drjit.latent` (which the package `neumat.export.drjit` imports)
PROGRAMS: dict[str, type] = {"healpix-mlp": HealpixMlp, "direction-mlp": DirectionMlp, "ggx": Ggx}


def programs() -> dict[str, type]:
    """`PROGRAMS`: every program module's entries (the package imports `.latent`, which registers its own)."""
    return PROGRAMS


def load_runtime(source, backend="llvm", compute: str | None = None, mlp_form: str | None = None) -> Runtime:
    """The Runtime of a drjit export. source: the export's folder or manifest.json, or (manifest, arrays) as a
    translator returns them; backend: see `backend_of` (e.g. `mitsuba.Float` for the current variant's);
    compute: "fp32" or "fp16" (default: fp16 on CUDA, fp32 on LLVM); mlp_form: `FORMS` (default: literal for fp32,
    coopvec for fp16; programs may choose otherwise, as NeuPreSS's wide layers take coopvec at fp32 on LLVM)."""
    manifest, arrays = source if isinstance(source, tuple) else read_export(source)
    b = backend_of(backend)
    if compute is None:
        compute = "fp16" if b.is_cuda else "fp32"
    if compute not in COMPUTE:
        raise InputError(f"drjit runtime compute: expected one of {', '.join(COMPUTE)}, got {compute!r}")
    if manifest.get("program") not in programs():
        raise DataFormatError(f"drjit export: unknown program {manifest.get('program')!r}")
    if mlp_form is not None and mlp_form not in FORMS:
        raise InputError(f"drjit runtime mlp_form: expected one of {', '.join(FORMS)}, got {mlp_form!r}")
    return PROGRAMS[manifest["program"]](manifest, arrays, b, compute, mlp_form)
