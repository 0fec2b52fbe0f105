"""Dr.Jit runtime programs of the latent-pyramid baselines (imports no torch); the pyramid, its anisotropic footprint
filter, the shading frame and the half / difference vectors are those of the "latent-mlp" program
(`neumat.export.drjit.latent`).

- "neumip" (`neumat.methods.latent_mlp.neumip`: neumip, neumip-offset, neumip-frame, nbrdf-uv):
  log f = MLP(z_s, directions), z_s the filtered spatial latent read at uv, or with the neural offset module at
  uv' = uv + h wo.xy / max(wo.z, offset_min_cos), h = MLP_o(z_o(uv), wo) / spatial_size; directions (wi, wo) in
  the geometric frame or in each learned shading frame (lifted to its hemisphere), or the Rusinkiewicz half and
  difference vectors; level selection "roulette" evaluates the expectation (1 - t) f(z_finer) + t f(z_coarser)
  as `NeuMIP.filtered_outputs` does outside training. The GLSL generator `neumat.methods.latent_mlp.glsl` computes
  the same in shader form.
- "ggx-mipmap" (`neumat.methods.latent_mlp.ggx_mipmap`): 12 GGX parameters filtered from the pyramid, decoded
  (softplus albedo and F0, normal slopes, rotated tangent, exp alpha clamped) and evaluated as one anisotropic GGX
  with a Lambertian term and the shading-normal cosine ratio.
"""
from __future__ import annotations

import math

import numpy as np

from ...core.errors import DataFormatError
from .latent import Pyramid, _lift, _linear, _unit, cross, frame_from_vectors, half_difference, to_local
from .runtime import PROGRAMS, Backend, Mlp, Runtime, mlp_layers


def _levels(arrays: dict, prefix: str) -> list:
    levels, i = [], 0
    while f"{prefix}{i}" in arrays:
        levels.append(arrays[f"{prefix}{i}"].astype(np.float32))
        i += 1
    if not levels:
        raise DataFormatError(f"drjit export: no pyramid levels {prefix}0, {prefix}1, ...")
    return levels


def _uv_footprint(b: Backend, uv, footprint):
    u, v = (b.Float(0.0), b.Float(0.0)) if uv is None else (b.Float(uv[0]), b.Float(uv[1]))
    return u, v, None if footprint is None else tuple(b.Float(x) for x in footprint)


class NeuMip(Runtime):
    """Program "neumip" (module docstring). Manifest: directions ("cartesian" / "rusinkiewicz"), frames (0: none),
    offset (bool), offset_min_cos, spatial_size, level_selection ("trilinear" / "roulette"), max_probes,
    activation. Arrays: level{l} (C, H_l, W_l) (the preconditioned pyramid), frame_weight (6 frames, C) (scale
    folded in) / frame_bias, offset_level{l}, offset_layer{i}_*, layer{i}_* (the last layer: the 3 log f rows)."""

    spatially_varying = True

    def __init__(self, manifest: dict, arrays: dict, backend: Backend, compute: str,
                 mlp_form: str | None = None) -> None:
        super().__init__(manifest, backend, compute, mlp_form)
        b = backend
        probes = int(manifest["max_probes"])
        self.pyramid = Pyramid(b, _levels(arrays, "level"), probes)
        self.directions = manifest["directions"]
        if self.directions not in ("cartesian", "rusinkiewicz"):
            raise DataFormatError(f"drjit export ({self.describe()}): unknown directions {self.directions!r}")
        self.frames = int(manifest.get("frames", 0))
        if self.frames:
            self.frame = (arrays["frame_weight"].astype(np.float32), arrays["frame_bias"].astype(np.float32))
            if self.frame[0].shape != (6 * self.frames, self.pyramid.channels):
                raise DataFormatError(f"drjit export ({self.describe()}): frame decoder does not match")
        self.roulette = manifest.get("level_selection", "trilinear") == "roulette"
        act = manifest.get("activation", "silu")
        self.offset = None
        if manifest.get("offset"):
            self.offset = (Pyramid(b, _levels(arrays, "offset_level"), probes),
                           Mlp(b, mlp_layers(arrays, "offset_layer"), act, compute, mlp_form),
                           float(manifest["spatial_size"]), float(manifest["offset_min_cos"]))
        self.mlp = Mlp(b, mlp_layers(arrays), act, compute, mlp_form)

    def _decode(self, z: list, wi: list, wo: list) -> list:
        """log f (3 Floats) of latent z at wi, wo (`NeuMIP.decode_outputs`)."""
        if self.frames:
            v = _linear(*self.frame, z)
            a, c = [], []
            for k in range(self.frames):
                t, bt, n = frame_from_vectors(v[6 * k:6 * k + 6])
                a += _lift(to_local(wi, t, bt, n))
                c += _lift(to_local(wo, t, bt, n))
        else:
            a, c = wi, wo
        if self.directions == "rusinkiewicz":
            h, d = half_difference(a, c)
            a, c = h, d
        return self.mlp(list(z) + list(a) + list(c))[:3]

    def eval(self, wi, wo, active=True, uv=None, footprint=None):
        import drjit as dr

        b = self.backend
        ok = b.Bool(active) & (wi[2] > 0) & (wo[2] > 0)
        a, c = [wi[0], wi[1], wi[2]], [wo[0], wo[1], wo[2]]
        u, v, fp = _uv_footprint(b, uv, footprint)
        if self.offset is not None:  # NeuMIP.offset_uv: the offset latent at uv, the depth, the parallax
            pyramid, mlp, size, min_cos = self.offset
            z_o = pyramid.filter(u, v, fp, ok)
            h = mlp(z_o + c)[0] / size
            inv = 1 / dr.maximum(c[2], min_cos)
            u, v = dr.fma(h * c[0], inv, u), dr.fma(h * c[1], inv, v)
        if self.roulette:
            t = self.pyramid.fraction(fp)
            fine = self._decode(self.pyramid.filter(u, v, fp, ok, "fine"), a, c)
            coarse = self._decode(self.pyramid.filter(u, v, fp, ok, "coarse"), a, c)
            out = [(1 - t) * dr.exp(x) + t * dr.exp(y) for x, y in zip(fine, coarse)]
        else:
            out = [dr.exp(x) for x in self._decode(self.pyramid.filter(u, v, fp, ok), a, c)]
        return dr.select(ok, b.Array3f(*out), 0.0)


def _softplus(x):
    """torch's softplus (threshold 20) with an accurate log1p (the albedo of a dark texel is exp(x) there)."""
    import drjit as dr

    e = dr.exp(dr.minimum(x, 20.0))
    u = 1 + e
    log1p = dr.select(u == 1, e, dr.log(u) * e / dr.select(u == 1, 1.0, u - 1))
    return dr.select(x > 20, x, log1p)


#: GGX mip-map's alpha clamp (`neumat.methods.latent_mlp.ggx_mipmap.MIN_ALPHA / MAX_ALPHA`)
MIN_ALPHA, MAX_ALPHA = 1e-3, 2.0
TINY = 1.1754944e-38


class GgxMipmap(Runtime):
    """Program "ggx-mipmap" (module docstring). Manifest: max_probes. Arrays: level{l} (12, H_l, W_l)."""

    spatially_varying = True

    def __init__(self, manifest: dict, arrays: dict, backend: Backend, compute: str,
                 mlp_form: str | None = None) -> None:
        super().__init__(manifest, backend, compute, mlp_form)
        self.pyramid = Pyramid(backend, _levels(arrays, "level"), int(manifest["max_probes"]))
        if self.pyramid.channels != 12:
            raise DataFormatError(f"drjit export ({self.describe()}): expected 12 GGX parameters per texel")

    def eval(self, wi, wo, active=True, uv=None, footprint=None):
        import drjit as dr

        b = self.backend
        ok = b.Bool(active) & (wi[2] > 0) & (wo[2] > 0)
        u, v, fp = _uv_footprint(b, uv, footprint)
        p = self.pyramid.filter(u, v, fp, ok)
        inv = 1 / dr.sqrt(p[6] * p[6] + p[7] * p[7] + 1)
        n = [p[6] * inv, p[7] * inv, inv]
        t = [1 - n[0] * n[0], -n[0] * n[1], -n[0] * n[2]]  # +x made orthogonal to n (frame_from_normal_tangent)
        inv_t = 1 / dr.sqrt(dr.maximum(t[0] * t[0] + t[1] * t[1] + t[2] * t[2], 1e-24))
        t = [x * inv_t for x in t]
        bt = cross(n, t)
        phi = 0.5 * dr.atan2(p[11], p[10])
        sp, cp = dr.sincos(phi)
        tangent = [cp * t[k] + sp * bt[k] for k in range(3)]
        bt = cross(n, tangent)
        ax = dr.clip(dr.exp(p[8]), MIN_ALPHA, MAX_ALPHA)
        ay = dr.clip(dr.exp(p[9]), MIN_ALPHA, MAX_ALPHA)
        li, lo = to_local(wi, tangent, bt, n), to_local(wo, tangent, bt, n)
        up = ok & (li[2] > 0) & (lo[2] > 0)
        li = [dr.select(up, x, z) for x, z in zip(li, (0.0, 0.0, 1.0))]
        lo = [dr.select(up, x, z) for x, z in zip(lo, (0.0, 0.0, 1.0))]
        h = _unit([li[k] + lo[k] for k in range(3)])

        def g1(w):
            z = dr.maximum(w[2], 0.0)
            root = dr.sqrt(w[2] * w[2] + (ax * w[0]) ** 2 + (ay * w[1]) ** 2)
            return 2 * z / dr.maximum(z + root, TINY)

        q = (h[0] / ax) ** 2 + (h[1] / ay) ** 2 + h[2] * h[2]
        ndf = dr.select(h[2] > 0, 1 / (math.pi * ax * ay * q * q), 0.0)
        s = ndf * g1(li) * g1(lo) / dr.maximum(4 * li[2] * lo[2], TINY)
        w5 = (1 - dr.clip(li[0] * h[0] + li[1] * h[1] + li[2] * h[2], 0.0, 1.0)) ** 5
        ratio = 0.5 * (li[2] / dr.maximum(wi[2], 1e-6) + lo[2] / dr.maximum(wo[2], 1e-6))
        out = []
        for k in range(3):
            f0 = _softplus(p[3 + k])
            out.append((_softplus(p[k]) / math.pi + (f0 + (1 - f0) * w5) * s) * ratio)
        return dr.select(up, b.Array3f(*out), 0.0)


PROGRAMS["neumip"] = NeuMip
PROGRAMS["ggx-mipmap"] = GgxMipmap
