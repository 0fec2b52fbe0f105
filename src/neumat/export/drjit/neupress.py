"""Dr.Jit runtime program "neupress" (imports no torch): NeuPreSS's S_hat(wi; x, wo) and its light sampler
(`neumat.methods.neupress.model.NeuPreSS`), what the scene integrator `neumat.integrations.mitsuba_translucent`
evaluates natively.

S_hat: Fourier features [cos(2 pi G v), sin(2 pi G v)] of v = (dir(wi), dir(wo), x scaled by the box), dir the
angles theta / pi, phi / 2 pi (or the unit vector, "cartesian"), the skip-connection ReLU MLP, clamped at 0. The
sampler: features of (position, dir(wo)), a ReLU MLP to log sigma (clamped), the azimuthal-equidistant Gaussian
lobe around n (`neumat.warp.azimuthal_gaussian`). `lobe(x, wo, n)` runs the sampler network once; its `sample` and
`pdf` share it. Object space, fp32; arrays and manifest: docs/formats/drjit.md.
"""
from __future__ import annotations

import math

import numpy as np

from ...core.errors import DataFormatError
from .runtime import PROGRAMS, Mlp, Runtime, mlp_layers

_TINY = float(np.finfo(np.float32).tiny)
_EPS = float(np.finfo(np.float32).eps)
_TWO_PI = float(np.float32(2 * math.pi))


def _expm1(x):
    """exp(x) - 1 with full relative accuracy near 0 (Kahan: (u - 1) x / log u)."""
    import drjit as dr

    u = dr.exp(x)
    um1 = u - 1
    safe = (u != 1) & (um1 != -1)
    return dr.select(u == 1, x, dr.select(um1 == -1, -1.0, um1 * x / dr.log(dr.select(safe, u, 2.0))))


def _log1p(x):
    """log(1 + x) with full relative accuracy near 0 (Goldberg: log(u) x / (u - 1), u = 1 + x)."""
    import drjit as dr

    u = 1 + x
    return dr.select(u == 1, x, dr.log(u) * x / dr.select(u == 1, 1.0, u - 1))


def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def frame_from_normal(n: list) -> tuple[list, list]:
    """`neumat.core.frames.frame_from_normal` (Duff et al.): tangent and bitangent of the unit normal n."""
    import drjit as dr

    x, y, z = n
    sign = dr.select(z >= 0, 1.0, -1.0)
    a = -1 / (sign + z)
    b = x * y * a
    return [1 + sign * x * x * a, sign * b, -sign * x], [b, sign + y * y * a, -y]


class Lobe:
    """The azimuthal-equidistant Gaussian lobe (axis n, sigma) of every lane, `AzimuthalGaussianLobe`'s Dr.Jit form:
    `sample(u0, u1)` -> (w, pdf), `pdf(w)`."""

    def __init__(self, axis: list, sigma) -> None:
        self.axis, self.sigma = list(axis), sigma
        self.truncation = _expm1(-0.5 * (math.pi / sigma) ** 2)  # -C

    def sample(self, u0, u1) -> tuple[list, object]:
        import drjit as dr

        arg = dr.maximum(u0 * self.truncation, -(1 - _EPS / 2))
        r = dr.minimum(self.sigma * dr.sqrt(dr.maximum(-2 * _log1p(arg), _TINY)), math.pi)
        phi = _TWO_PI * u1
        s = dr.sin(r)
        local = [s * dr.cos(phi), s * dr.sin(phi), dr.cos(r)]
        t, b = frame_from_normal(self.axis)
        w = [local[0] * t[k] + local[1] * b[k] + local[2] * self.axis[k] for k in range(3)]
        return w, self.pdf(w)

    def pdf(self, w: list):
        import drjit as dr

        n = self.axis
        dv = [w[k] - n[k] for k in range(3)]
        sv = [w[k] + n[k] for k in range(3)]
        d2, s2 = dr.maximum(_dot(dv, dv), _TINY), dr.maximum(_dot(sv, sv), _TINY)
        d, s = dr.sqrt(d2), dr.sqrt(s2)
        theta = 2 * dr.atan2(d, s)
        ratio = theta * (d2 + s2) / (2 * d * s)
        norm = -2 * math.pi * self.sigma * self.sigma * self.truncation
        return dr.exp(-0.5 * (theta / self.sigma) ** 2) / norm * ratio


class NeuPress(Runtime):
    """Program "neupress" (module docstring). Not a BSDF: `eval(wi, wo, active, x=x)` is S_hat (Array3f, clamped at
    0, 0 on inactive lanes) at object-space position x; `sigma(x, wo)`, `lobe(x, wo, n)`, `sample_incident(x, wo,
    n, u0, u1)` -> (wi, pdf), `incident_pdf(wi, x, wo, n)`. The MLPs default to the "coopvec" form (its 128-wide
    layers and 512 features make the literal form's kernels slow to compile); mlp_form="literal" selects the other."""

    full_sphere = True
    translucent = True  # an object's S_hat for `neumat_translucent`, not a surface BSDF

    def __init__(self, manifest: dict, arrays: dict, backend, compute: str, mlp_form: str | None = None) -> None:
        super().__init__(manifest, backend, compute, mlp_form)
        self.encoding = manifest.get("direction_encoding", "spherical")
        if self.encoding not in ("spherical", "cartesian"):
            raise DataFormatError(f"drjit export ({self.describe()}): unknown direction_encoding {self.encoding!r}")
        self.skips = bool(manifest.get("skips", True))
        self.box_min = np.asarray(manifest["box_min"], np.float32)
        self.box_max = np.asarray(manifest["box_max"], np.float32)
        self.extent = (self.box_max - self.box_min).astype(np.float32)
        self.log_sigma = (math.log(float(manifest["sigma_min"])), math.log(float(manifest["sigma_max"])))
        d = 2 if self.encoding == "spherical" else 3
        self.g_app = np.asarray(arrays["appearance_G"], np.float32)
        self.g_smp = np.asarray(arrays["sampler_G"], np.float32)
        if self.g_app.shape[1] != 2 * d + 3 or self.g_smp.shape[1] != d + 3 or self.box_min.shape != (3,):
            raise DataFormatError(f"drjit export ({self.describe()}): Fourier matrices or box do not match the "
                                  "manifest")
        if mlp_form is None and compute == "fp32" and not backend.is_cuda:
            mlp_form = "coopvec"
        self.mlp_form = mlp_form

        def layer(w, b):
            return Mlp(backend, [(w, b)], "relu", compute, mlp_form)

        self.first = layer(arrays["app_first_weight"], arrays["app_first_bias"])
        self.hidden = [layer(w, b) for w, b in mlp_layers(arrays, "app_hidden")]
        self.out = layer(arrays["app_out_weight"], arrays["app_out_bias"])
        sampler = mlp_layers(arrays, "sampler")
        if not sampler or np.shape(sampler[-1][0])[0] != 1 or \
                np.shape(arrays["app_first_weight"])[1] != 2 * len(self.g_app) or \
                np.shape(sampler[0][0])[1] != 2 * len(self.g_smp) or np.shape(arrays["app_out_weight"])[0] != 3:
            raise DataFormatError(f"drjit export ({self.describe()}): layer shapes do not match the features")
        self.sampler = Mlp(backend, sampler, "relu", compute, mlp_form)

    # ---- inputs ---------------------------------------------------------------------------------------------
    def _direction(self, w) -> list:
        import drjit as dr

        if self.encoding == "cartesian":
            return [w[0], w[1], w[2]]
        theta = dr.acos(dr.clip(w[2], -1.0, 1.0))
        phi = dr.atan2(w[1], w[0])
        phi = dr.select(phi < 0, phi + _TWO_PI, phi)
        return [theta / float(np.float32(math.pi)), phi / _TWO_PI]

    def _position(self, x) -> list:
        return [(x[k] - float(self.box_min[k])) / float(self.extent[k]) for k in range(3)]

    @staticmethod
    def _features(g: np.ndarray, v: list) -> list:
        import drjit as dr

        a = []
        for row in g.tolist():
            acc = v[0] * row[0]
            for value, c in zip(v[1:], row[1:]):
                acc = dr.fma(value, c, acc)
            a.append(acc * _TWO_PI)
        return [dr.cos(t) for t in a] + [dr.sin(t) for t in a]

    @staticmethod
    def _relu(h: list) -> list:
        import drjit as dr
        return [dr.maximum(v, 0.0) for v in h]

    # ---- S_hat --------------------------------------------------------------------------------------------
    def raw(self, wi, x, wo) -> list:
        """The unclamped network output (3 Floats)."""
        h = self._relu(self.first(self._features(self.g_app, self._direction(wi) + self._direction(wo)
                                                 + self._position(x))))
        pairs = len(self.hidden) // 2
        for k in range(pairs):
            t = self.hidden[2 * k + 1](self._relu(self.hidden[2 * k](h)))
            h = self._relu([a + c for a, c in zip(h, t)] if self.skips else t)
        if len(self.hidden) % 2:
            h = self._relu(self.hidden[-1](h))
        return self.out(h)

    def eval(self, wi, wo, active=True, uv=None, footprint=None, x=None):
        import drjit as dr

        if x is None:
            raise DataFormatError("neupress runtime: eval needs the object-space position x")
        out = self.raw(wi, x, wo)
        return dr.select(self.backend.Bool(active), self.backend.Array3f(*(dr.maximum(v, 0.0) for v in out)), 0.0)

    # ---- the light sampler --------------------------------------------------------------------------------
    def sigma(self, x, wo):
        """Standard deviation (radians) of the sampling lobe at x for view wo."""
        import drjit as dr

        log_sigma = self.sampler(self._features(self.g_smp, self._position(x) + self._direction(wo)))[0]
        return dr.exp(dr.clip(log_sigma, *self.log_sigma))

    def lobe(self, x, wo, n) -> Lobe:
        return Lobe([n[0], n[1], n[2]], self.sigma(x, wo))

    def sample_incident(self, x, wo, n, u0, u1, active=True):
        """(wi Array3f, pdf Float): light directions drawn from the lobe around n and their solid-angle pdf."""
        import drjit as dr

        w, pdf = self.lobe(x, wo, n).sample(u0, u1)
        active = self.backend.Bool(active)
        return dr.select(active, self.backend.Array3f(*w), 0.0), dr.select(active, pdf, 0.0)

    def incident_pdf(self, wi, x, wo, n, active=True):
        import drjit as dr

        return dr.select(self.backend.Bool(active), self.lobe(x, wo, n).pdf([wi[0], wi[1], wi[2]]), 0.0)


PROGRAMS["neupress"] = NeuPress
