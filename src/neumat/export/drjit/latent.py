"""Dr.Jit runtime programs of the latent-texture family (imports no torch).

- "latent-mlp" (the multi-scale gated model of Timonen et al. 2025 and its configurations: tripleplane, the
  homogeneous variant, the ablations): the spatial latent z_s read from a mip pyramid with the anisotropic
  footprint filter of `neumat.nn.latent_texture.filter_anisotropic` (bilinear at the finest level without a
  footprint), the learned shading frame (`neumat.nn.shading_frames`), half / difference vectors in disk-polar
  coordinates, the radial warps (`neumat.nn.radial_warp`), the two angular textures
  (`neumat.nn.angular_texture`), gating (z_h = H z_s, z_d = D z_s) or concatenation, the SiLU MLP and exp.
  The GLSL generator `neumat.methods.latent_mlp.glsl_multiscale` computes the same in shader form.

Texels are stored channel-last so that one lookup is one packet gather of C contiguous floats.
"""
from __future__ import annotations

import math

import numpy as np

from ...core.errors import DataFormatError
from .runtime import PROGRAMS, Backend, Mlp, Runtime, mlp_layers

#: smallest radial-warp exponent (`neumat.nn.radial_warp.MIN_ALPHA`)
MIN_ALPHA = 0.5


def _gather(b: Backend, source, index, active, channels: int) -> list:
    """Row `index` (UInt) of `source` seen as rows of `channels` floats, as a list of Floats (one packet gather)."""
    import drjit as dr

    n = dr.width((index, active))
    rows = dr.gather(b.ArrayXf, source, index, active, shape=(channels, n))
    return [rows[j] for j in range(channels)]


class Pyramid:
    """Mip levels (C, H_l, W_l), finest first, wrap tiling, texel (i, j) at uv ((j + 1/2) / W, 1 - (i + 1/2) / H)
    (`neumat.nn.latent_texture`). `filter(u, v, footprint)` -> C Floats."""

    def __init__(self, b: Backend, levels: list[np.ndarray], max_probes: int) -> None:
        import drjit as dr

        self.backend, self.max_probes = b, int(max_probes)
        self.channels = int(levels[0].shape[0])
        self.sizes = [(int(t.shape[1]), int(t.shape[2])) for t in levels]
        if any(t.ndim != 3 or t.shape[0] != self.channels for t in levels):
            raise DataFormatError("drjit export: pyramid levels must be (C, H, W) with one C")
        offsets = np.cumsum([0] + [h * w for h, w in self.sizes])[:-1]
        self.data = b.Float(np.concatenate([np.ascontiguousarray(t.transpose(1, 2, 0), np.float32).ravel()
                                            for t in levels]))
        self.offset = b.UInt(offsets.astype(np.uint32))
        self.width = b.UInt(np.array([w for _, w in self.sizes], np.uint32))
        self.height = b.UInt(np.array([h for h, _ in self.sizes], np.uint32))
        dr.eval(self.data, self.offset, self.width, self.height)

    def bilinear(self, level, u, v, weight, active) -> list:
        """weight x the bilinear lookup (wrap tiling) of level `level` (UInt) at (u, v) in [0, 1)."""
        import drjit as dr

        b = self.backend
        w = dr.gather(b.UInt, self.width, level, active)
        h = dr.gather(b.UInt, self.height, level, active)
        base = dr.gather(b.UInt, self.offset, level, active)
        x = u * b.Float(w) - 0.5
        y = (1 - v) * b.Float(h) - 0.5
        x0f, y0f = dr.floor(x), dr.floor(y)
        fx, fy = x - x0f, y - y0f
        wi, hi = b.Int(w), b.Int(h)
        x0, y0 = b.Int(x0f), b.Int(y0f)  # in [-1, W - 1], [-1, H - 1]
        x1, y1 = x0 + 1, y0 + 1
        x0 = dr.select(x0 < 0, x0 + wi, x0)
        y0 = dr.select(y0 < 0, y0 + hi, y0)
        x1 = dr.select(x1 >= wi, x1 - wi, x1)
        y1 = dr.select(y1 >= hi, y1 - hi, y1)
        c = self.channels
        out = None
        for yy, xx, wgt in ((y0, x0, (1 - fx) * (1 - fy)), (y0, x1, fx * (1 - fy)), (y1, x0, (1 - fx) * fy),
                            (y1, x1, fx * fy)):
            texel = _gather(b, self.data, base + b.UInt(yy * wi + xx), active, c)
            wgt = wgt * weight
            out = [t * wgt for t in texel] if out is None else [dr.fma(t, wgt, o) for t, o in zip(texel, out)]
        return out

    def trilinear(self, u, v, lod, scale, active, pick: str | None = None) -> list:
        """scale x the trilinear lookup at lod (clamped to the pyramid) of uv (wrapped), `trilinear_flat`; pick
        "fine" / "coarse": only the finer / the coarser of the two levels (`trilinear_flat`'s level_u 1 / 0, the
        coarser only where the lod has a fractional part)."""
        import drjit as dr

        b = self.backend
        u, v = u - dr.floor(u), v - dr.floor(v)
        lod = dr.clip(lod, 0.0, len(self.sizes) - 1.0)
        lo = dr.floor(lod)
        t = lod - lo
        if pick == "fine":
            t = b.Float(0.0)
        elif pick == "coarse":
            t = dr.select(t > 0, 1.0, 0.0)
        l0 = b.UInt(lo)
        l1 = dr.minimum(l0 + 1, len(self.sizes) - 1)
        a = self.bilinear(l0, u, v, (1 - t) * scale, active)
        c = self.bilinear(l1, u, v, t * scale, active)
        return [x + y for x, y in zip(a, c)]

    def _geometry(self, footprint):
        """(theta, major, n, sigma, lod) of `_probe_geometry` for the footprint (s_uu, s_uv, s_vv)."""
        import drjit as dr

        h0, w0 = self.sizes[0]
        p = self.max_probes
        sa, sb, sc = footprint
        a, bb, c = sa * (w0 * w0), sb * (w0 * h0), sc * (h0 * h0)  # in level-0 texels^2
        mean = (a + c) / 2
        half = dr.sqrt(((a - c) / 2) ** 2 + bb * bb)
        theta = 0.5 * dr.atan2(2 * bb, a - c)
        major = dr.sqrt(dr.maximum(mean + half, 0.0))
        minor = dr.maximum(dr.sqrt(dr.maximum(mean - half, 0.0)), 1e-12)
        n = dr.clip(dr.ceil(major / minor), 1.0, float(p))
        sigma = dr.maximum(minor, major / p)
        return theta, major, n, sigma, dr.log2(dr.maximum(2 * sigma, 1e-12))

    def fraction(self, footprint):
        """Weight t of the coarser of the two levels the footprint's probes read (`LatentPyramid.level_fraction`;
        0 without a footprint)."""
        import drjit as dr

        if footprint is None:
            return self.backend.Float(0.0)
        lod = dr.clip(self._geometry(footprint)[4], 0.0, len(self.sizes) - 1.0)
        return lod - dr.floor(lod)

    def filter(self, u, v, footprint, active, pick: str | None = None) -> list:
        """z (C Floats) at uv filtered over the footprint (s_uu, s_uv, s_vv) covariance in uv^2: the probes of
        `filter_anisotropic` (a Dr.Jit loop over each lane's probe count); None: bilinear at the finest level.
        pick: as `trilinear` (Russian-roulette level selection's two outcomes)."""
        import drjit as dr

        b = self.backend
        if footprint is None:
            return self.bilinear(b.UInt(0), u - dr.floor(u), v - dr.floor(v), b.Float(1.0), active)
        h0, w0 = self.sizes[0]
        theta, major, n, sigma, lod = self._geometry(footprint)
        spacing = dr.sqrt(dr.maximum(12 * (major * major - sigma * sigma), 0.0) / dr.maximum(n * n - 1, 1.0))
        ax, ay = dr.cos(theta) / w0, dr.sin(theta) / h0
        inv_n = 1 / n
        first = (n - 1) / 2

        def body(k, *acc):
            offset = (k - first) * spacing
            z = self.trilinear(u + offset * ax, v + offset * ay, lod, inv_n, active, pick)
            return (k + 1, *(s + x for s, x in zip(acc, z)))

        state = dr.while_loop(state=(b.Float(0.0), *[b.Float(0.0) for _ in range(self.channels)]),
                              cond=lambda k, *acc: active & (k < n), body=body,
                              max_iterations=-1)  # a sum over probes: reverse-mode AD of the latents needs the hint
        return list(state[1:])


class Angular:
    """A polar texture (C, R, P) (`neumat.nn.angular_texture.AngularTexture`): rows at r = i / (R - 1), columns at
    phi = (j + 1/2) period / P, circular in phi, the pole row single-valued. `read(r, phi)` -> C Floats."""

    def __init__(self, b: Backend, texture: np.ndarray, period: float) -> None:
        import drjit as dr

        c, r, p = texture.shape
        self.backend, self.channels, self.radial, self.angular, self.period = b, c, r, p, float(period)
        rows = np.concatenate([np.broadcast_to(texture[:, :1, :1], (c, 1, p)), texture[:, 1:]], 1)
        padded = np.concatenate([rows[:, :, -1:], rows, rows[:, :, :1]], 2)  # (C, R, P + 2)
        self.data = b.Float(np.ascontiguousarray(padded.transpose(1, 2, 0), np.float32).ravel())
        dr.eval(self.data)

    def read(self, r, phi, active) -> list:
        import drjit as dr

        b = self.backend
        phi = phi - dr.floor(phi / self.period) * self.period
        x = phi * (self.angular / self.period) + 0.5  # padded column, in [1/2, P + 1/2]
        y = dr.clip(r, 0.0, 1.0) * (self.radial - 1)
        x0f, y0f = dr.floor(x), dr.floor(y)
        fx, fy = x - x0f, y - y0f
        x0, y0 = b.UInt(x0f), b.UInt(y0f)
        x1, y1 = x0 + 1, dr.minimum(y0 + 1, self.radial - 1)
        width, c = self.angular + 2, self.channels
        out = None
        for yy, xx, wgt in ((y0, x0, (1 - fx) * (1 - fy)), (y0, x1, fx * (1 - fy)), (y1, x0, (1 - fx) * fy),
                            (y1, x1, fx * fy)):
            texel = _gather(b, self.data, yy * width + xx, active, c)
            out = [t * wgt for t in texel] if out is None else [dr.fma(t, wgt, o) for t, o in zip(texel, out)]
        return out


def _linear(weight: np.ndarray, bias: np.ndarray, x: list) -> list:
    """W x + b with constant weights (unrolled fma)."""
    import drjit as dr

    out = []
    for row, b0 in zip(np.asarray(weight, np.float32).tolist(), np.asarray(bias, np.float32).tolist()):
        acc = None
        for v, c in zip(x, row):
            acc = v * c if acc is None else dr.fma(v, c, acc)
        out.append(acc + b0 if acc is not None else b0)
    return out


def _unit(v: list, eps: float = 1e-12) -> list:
    import drjit as dr

    inv = 1 / dr.maximum(dr.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]), eps)
    return [x * inv for x in v]


def _lift(w: list) -> list:
    import drjit as dr

    return [w[0], w[1], dr.sqrt(dr.maximum(1 - (w[0] * w[0] + w[1] * w[1]), 1e-10))]


def cross(a: list, b: list) -> list:
    return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]


def to_local(w: list, t: list, b: list, n: list) -> list:
    """w in the frame (t, b, n) (`neumat.core.frames.to_local`)."""
    return [w[0] * e[0] + w[1] * e[1] + w[2] * e[2] for e in (t, b, n)]


def frame_from_vectors(v: list) -> tuple[list, list, list]:
    """(t, b, n) of a decoded (normal, tangent) 6-vector (`neumat.nn.shading_frames.frame_from_vectors`)."""
    n = _unit(v[:3])
    t = v[3:6]
    dot = t[0] * n[0] + t[1] * n[1] + t[2] * n[2]
    t = _unit([t[k] - dot * n[k] for k in range(3)])
    return t, cross(n, t), n


def half_difference(wi: list, wo: list) -> tuple[list, list]:
    """`neumat.nn.angular_texture.half_difference`: h and d (pole: |h_xy|^2 < 1e-14, phi_h = 0 there)."""
    import drjit as dr

    h = _unit([wi[k] + wo[k] for k in range(3)])
    s2 = h[0] * h[0] + h[1] * h[1]
    pole = s2 < 1e-14
    s = dr.sqrt(dr.select(pole, 1.0, s2))
    cos_phi = dr.select(pole, 1.0, h[0] / s)
    sin_phi = dr.select(pole, 0.0, h[1] / s)
    sin_theta = dr.select(pole, 0.0, s)
    cos_theta = h[2]
    x = cos_phi * wi[0] + sin_phi * wi[1]
    y = -sin_phi * wi[0] + cos_phi * wi[1]
    return h, [cos_theta * x - sin_theta * wi[2], y, sin_theta * x + cos_theta * wi[2]]


def disk_polar(w: list, period: float):
    """`neumat.nn.angular_texture.disk_polar`: (r, phi in [0, period))."""
    import drjit as dr

    x, y = w[0], w[1]
    r2 = x * x + y * y
    pole = r2 < 1e-14
    r = dr.minimum(dr.select(pole, 0.0, dr.sqrt(dr.select(pole, 1.0, r2))), 1.0)
    phi = dr.atan2(dr.select(pole, 0.0, y), dr.select(pole, 1.0, x))
    return r, phi - dr.floor(phi / period) * period


def _softplus(x):
    import drjit as dr

    return dr.select(x > 20, x, dr.log(1 + dr.exp(dr.minimum(x, 20.0))))


class LatentMlp(Runtime):
    """Program "latent-mlp" (module docstring). Manifest: spatial (bool), gating, frame, warps, channels
    (spatial, half, diff), warp_terms, max_probes, activation ("silu"), output ("exp"), output_bound (the output's
    per-channel bound: three numbers, or absent / null for none). Arrays: level{l} (C, H_l, W_l) (the
    preconditioned pyramid), half_texture / diff_texture (C, R, P), frame_weight (6, C) (scale folded in) /
    frame_bias, warp_h_* / warp_d_* (weight (2K, C) and bias, or params (2K,)), layer{i}_*."""

    def __init__(self, manifest: dict, arrays: dict, backend: Backend, compute: str,
                 mlp_form: str | None = None) -> None:
        super().__init__(manifest, backend, compute, mlp_form)
        b = backend
        self.spatially_varying = bool(manifest["spatial"])
        self.gating = bool(manifest["gating"]) and self.spatially_varying
        self.ds, self.dh, self.dd = (int(v) for v in manifest["channels"])
        self.terms = int(manifest["warp_terms"])
        self.half = Angular(b, arrays["half_texture"].astype(np.float32), 2 * math.pi)
        self.diff = Angular(b, arrays["diff_texture"].astype(np.float32), math.pi)
        gate = self.ds if self.gating else 1
        if self.half.channels != self.dh * gate or self.diff.channels != self.dd * gate:
            raise DataFormatError(f"drjit export ({self.describe()}): angular textures do not match the channels")
        self.pyramid = None
        if self.spatially_varying:
            levels, i = [], 0
            while f"level{i}" in arrays:
                levels.append(arrays[f"level{i}"].astype(np.float32))
                i += 1
            self.pyramid = Pyramid(b, levels, int(manifest["max_probes"]))
            if self.pyramid.channels != self.ds:
                raise DataFormatError(f"drjit export ({self.describe()}): pyramid channels do not match")
        self.frame = None
        if manifest.get("frame"):
            self.frame = (arrays["frame_weight"].astype(np.float32), arrays["frame_bias"].astype(np.float32))
        self.warps = {}
        if manifest.get("warps"):
            for tag in ("h", "d"):
                if f"warp_{tag}_params" in arrays:  # constant: softmax weights and exponents computed once
                    p = arrays[f"warp_{tag}_params"].astype(np.float32)
                    logits, raw = p[:self.terms], p[self.terms:]
                    e = np.exp(logits - logits.max())
                    alpha = MIN_ALPHA + np.where(raw > 20, raw, np.log1p(np.exp(np.minimum(raw, 20))))
                    self.warps[tag] = ("const", (e / e.sum()).astype(np.float32).tolist(),
                                       alpha.astype(np.float32).tolist())
                else:
                    self.warps[tag] = ("decode", arrays[f"warp_{tag}_weight"].astype(np.float32),
                                       arrays[f"warp_{tag}_bias"].astype(np.float32))
        self.mlp = Mlp(b, mlp_layers(arrays), manifest.get("activation", "silu"), compute, mlp_form)
        bound = manifest.get("output_bound")
        if bound is not None and (not isinstance(bound, list) or len(bound) != 3 or not all(
                isinstance(x, (int, float)) and math.isfinite(x) and x > 0 for x in bound)):
            raise DataFormatError(f"drjit export ({self.describe()}): output_bound must be three positive numbers, "
                                  f"got {bound!r}")
        self.bound = bound

    def _warp(self, tag: str, r, z):
        import drjit as dr

        kind, w, alpha = self.warps[tag]
        if kind == "decode":
            p = _linear(w, alpha, z)
            logits, raw = p[:self.terms], p[self.terms:]
            top = logits[0]
            for x in logits[1:]:
                top = dr.maximum(top, x)
            e = [dr.exp(x - top) for x in logits]
            total = e[0]
            for x in e[1:]:
                total = total + x
            w = [x / total for x in e]
            alpha = [MIN_ALPHA + _softplus(x) for x in raw]
        log_r = dr.log(dr.clip(r, 1e-9, 1.0))
        out = None
        for wk, ak in zip(w, alpha):
            term = wk * dr.exp(ak * log_r)
            out = term if out is None else out + term
        return out

    def eval(self, wi, wo, active=True, uv=None, footprint=None):
        import drjit as dr

        b = self.backend
        ok = b.Bool(active) & (wi[2] > 0) & (wo[2] > 0)
        a, c = [wi[0], wi[1], wi[2]], [wo[0], wo[1], wo[2]]
        z = None
        if self.pyramid is not None:
            if uv is None:
                u = v = b.Float(0.0)
            else:
                u, v = b.Float(uv[0]), b.Float(uv[1])
            if footprint is not None:
                footprint = tuple(b.Float(x) for x in footprint)
            z = self.pyramid.filter(u, v, footprint, ok)
        if self.frame is not None:
            t, bt, nrm = frame_from_vectors(_linear(*self.frame, z))
            a, c = _lift(to_local(a, t, bt, nrm)), _lift(to_local(c, t, bt, nrm))
        else:
            a, c = _lift(a), _lift(c)
        h, d = half_difference(a, c)
        r_h, phi_h = disk_polar(h, 2 * math.pi)
        r_d, phi_d = disk_polar(d, math.pi)
        if self.warps:
            r_h, r_d = self._warp("h", r_h, z), self._warp("d", r_d, z)
        a_h, a_d = self.half.read(r_h, phi_h, ok), self.diff.read(r_d, phi_d, ok)
        if self.gating:
            x = []
            for tex, dim in ((a_h, self.dh), (a_d, self.dd)):
                for o in range(dim):
                    acc = tex[o * self.ds] * z[0]
                    for i in range(1, self.ds):
                        acc = dr.fma(tex[o * self.ds + i], z[i], acc)
                    x.append(acc)
        else:
            x = a_h + a_d + (z if z is not None else [])
        out = [dr.exp(v) for v in self.mlp(x)]
        if self.bound is not None:
            out = [dr.minimum(v, bound) for v, bound in zip(out, self.bound)]
        return dr.select(ok, b.Array3f(*out), 0.0)


PROGRAMS["latent-mlp"] = LatentMlp
