"""Dr.Jit runtime program "sparse-btf" (imports no torch): SparseBTF's decode (`neumat.methods.sparse_btf.model`,
`SparseBTF.eval`), one BTF element per query, in either angular mode of the model (manifest "angular"):

- the k nearest light bins of wi and view bins of wo (largest dot product, `angular_weights`), weighted by
  normalised inverse angular distance (atan2(|w x d|, w . d); an exact hit gets weight 1);
- the 4 wrap-around bilinear taps of uv (`bilinear_taps`), each in its p x p data point;
- "coefficient" (Eq. 6, as the GLSL export `neumat.methods.sparse_btf.glsl`): per YUV channel c, z_c = sum_taps
  w_tap sum_j v_j U1[x1, i1] U2[x2, i2] (sum_a lw_a U3[l_a, i3]) (sum_b vw_b U4[v_b, i4]) over the data point's
  sparse coefficients (v_j, i1..i4) in dictionary `membership`; f = max(exp(YUV_TO_RGB (z std + mean)) - eps, 0),
  std and mean interpolated with the same bin weights;
- "value": z_c per tap and bin pair (a, b) with U3[l_a, i3] U4[v_b, i4], each standardised with its own bin's
  std and mean and taken to linear RGB as above, then f = sum w_tap lw_a vw_b rgb (the decoded table, interpolated);
- 0 below either horizon.
"""
from __future__ import annotations

import numpy as np

from ...core.errors import DataFormatError
from .runtime import PROGRAMS, Backend, Runtime

#: `neumat.methods.sparse_btf.dictionary.YUV_TO_RGB` (the inverse of its RGB_TO_YUV, rounded to float32)
RGB_TO_YUV = np.array([[0.299, 0.587, 0.114], [-0.14713, -0.28886, 0.436], [0.615, -0.51499, -0.10001]])
YUV_TO_RGB = np.linalg.inv(RGB_TO_YUV).astype(np.float32)


def _nearest(b: Backend, table: np.ndarray, w: list, k: int) -> tuple[list, list]:
    """Indices (k UInts) and weights (k Floats) of the k bins of `table` (D, 3) nearest to w (`angular_weights`):
    an insertion of every bin into the running top k (the table's directions are constants of the kernel)."""
    import drjit as dr

    k = min(k, len(table))
    best = [b.Float(-3.0) for _ in range(k)]
    idx = [b.UInt(0) for _ in range(k)]
    dirs = [[b.Float(0.0)] * 3 for _ in range(k)]
    for j, (x, y, z) in enumerate(np.asarray(table, np.float32).tolist()):
        cd, ci, cv = w[0] * x + w[1] * y + w[2] * z, b.UInt(j), [b.Float(x), b.Float(y), b.Float(z)]
        for s in range(k):
            take = cd > best[s]
            best[s], cd = dr.select(take, cd, best[s]), dr.select(take, best[s], cd)
            idx[s], ci = dr.select(take, ci, idx[s]), dr.select(take, idx[s], ci)
            dirs[s], cv = ([dr.select(take, cv[q], dirs[s][q]) for q in range(3)],
                           [dr.select(take, dirs[s][q], cv[q]) for q in range(3)])
    angles = []
    for d in dirs:
        cx = w[1] * d[2] - w[2] * d[1]
        cy = w[2] * d[0] - w[0] * d[2]
        cz = w[0] * d[1] - w[1] * d[0]
        angles.append(dr.atan2(dr.sqrt(cx * cx + cy * cy + cz * cz), w[0] * d[0] + w[1] * d[1] + w[2] * d[2]))
    exact = [a <= 1e-7 for a in angles]
    any_exact = exact[0]
    for e in exact[1:]:
        any_exact = any_exact | e
    inv = [dr.select(any_exact, dr.select(e, 1.0, 0.0), 1 / dr.maximum(a, 1e-7)) for a, e in zip(angles, exact)]
    total = inv[0]
    for v in inv[1:]:
        total = total + v
    return idx, [v / total for v in inv]


class SparseBtf(Runtime):
    """Program "sparse-btf" (module docstring). Manifest: patch, num_dictionaries, n_light, n_view, height, width,
    log_eps, neighbours, angular ("coefficient" where absent: exports made before "value" had a program). Arrays:
    dict_1 .. dict_4 (3, K, m, m), values (3, P, T), index (3, P, T, 4), membership and counts (3, P), mean and std
    (L, V, 3), light_dirs (L, 3), view_dirs (V, 3)."""

    spatially_varying = True

    def __init__(self, manifest: dict, arrays: dict, backend: Backend, compute: str,
                 mlp_form: str | None = None) -> None:
        super().__init__(manifest, backend, compute, mlp_form)
        import drjit as dr

        b = backend
        self.p, self.k = int(manifest["patch"]), int(manifest["num_dictionaries"])
        self.n_light, self.n_view = int(manifest["n_light"]), int(manifest["n_view"])
        self.height, self.width = int(manifest["height"]), int(manifest["width"])
        self.eps, self.neighbours = float(manifest["log_eps"]), int(manifest["neighbours"])
        self.angular = manifest.get("angular", "coefficient")
        if self.angular not in ("coefficient", "value"):
            raise DataFormatError(f"drjit export ({self.describe()}): unknown angular interpolation {self.angular!r}")
        self.patches = (self.height // self.p) * (self.width // self.p)
        values = arrays["values"].astype(np.float32)
        self.t = int(values.shape[2])
        shapes = {"values": (3, self.patches, self.t), "index": (3, self.patches, self.t, 4),
                  "membership": (3, self.patches), "counts": (3, self.patches),
                  "mean": (self.n_light, self.n_view, 3), "std": (self.n_light, self.n_view, 3),
                  "light_dirs": (self.n_light, 3), "view_dirs": (self.n_view, 3)}
        for n, m in enumerate((self.p, self.p, self.n_light, self.n_view), start=1):
            shapes[f"dict_{n}"] = (3, self.k, m, m)
        if any(tuple(arrays[name].shape) != shape for name, shape in shapes.items()):
            raise DataFormatError(f"drjit export ({self.describe()}): array shapes do not match the manifest")
        self.dicts = [b.Float(arrays[f"dict_{n}"].astype(np.float32).ravel()) for n in range(1, 5)]
        self.values = b.Float(values.ravel())
        self.index = b.UInt(arrays["index"].astype(np.uint32).ravel())
        self.membership = b.UInt(arrays["membership"].astype(np.uint32).ravel())
        self.counts = b.UInt(arrays["counts"].astype(np.uint32).ravel())
        self.mean = b.Float(arrays["mean"].astype(np.float32).ravel())
        self.std = b.Float(arrays["std"].astype(np.float32).ravel())
        self.light_dirs = arrays["light_dirs"].astype(np.float32)
        self.view_dirs = arrays["view_dirs"].astype(np.float32)
        dr.eval(self.dicts, self.values, self.index, self.membership, self.counts, self.mean, self.std)

    def _taps(self, u, v):
        """(patch, x1, x2, weight) of the 4 bilinear taps of uv (`SparseBTF._texels`)."""
        import drjit as dr

        b, p, h, w = self.backend, self.p, self.height, self.width
        x = u * w - 0.5
        y = (1 - v) * h - 0.5
        x0, y0 = dr.floor(x), dr.floor(y)
        fx, fy = x - x0, y - y0
        taps = []
        for dy, dx, wgt in ((0, 0, (1 - fx) * (1 - fy)), (0, 1, fx * (1 - fy)), (1, 0, (1 - fx) * fy),
                            (1, 1, fx * fy)):
            cf, rf = x0 + dx, y0 + dy
            col = b.UInt(cf - dr.floor(cf / w) * w)  # Python's (non-negative) remainder
            row = b.UInt(rf - dr.floor(rf / h) * h)
            col, row = dr.minimum(col, w - 1), dr.minimum(row, h - 1)
            patch = (row // p) * (w // p) + col // p
            taps.append((patch, row % p, col % p, wgt))
        return taps

    def eval(self, wi, wo, active=True, uv=None, footprint=None):
        import drjit as dr

        b = self.backend
        ok = b.Bool(active) & (wi[2] > 0) & (wo[2] > 0)
        wl, wv = [wi[0], wi[1], wi[2]], [wo[0], wo[1], wo[2]]
        li, lw = _nearest(b, self.light_dirs, wl, self.neighbours)
        vi, vw = _nearest(b, self.view_dirs, wv, self.neighbours)
        u, v = (b.Float(0.0), b.Float(0.0)) if uv is None else (b.Float(uv[0]), b.Float(uv[1]))
        taps = self._taps(u, v)
        p, k, t, patches = self.p, self.k, self.t, self.patches
        d1, d2, d3, d4 = self.dicts
        nl, nv = self.n_light, self.n_view
        # per channel and tap: the data point's dictionary and the offsets of its coefficient rows
        per = []
        for c in range(3):
            for patch, x1, x2, wgt in taps:
                point = c * patches + patch
                memb = dr.gather(b.UInt, self.membership, point, ok)
                count = dr.gather(b.UInt, self.counts, point, ok)
                dm = c * k + memb
                per.append((c, point * t, count, wgt, ((dm * p + x1) * p), ((dm * p + x2) * p),
                            [(dm * nl + a) * nl for a in li], [(dm * nv + a) * nv for a in vi]))
        value = self.angular == "value"
        bins = len(li) * len(vi)

        def body(j, *z):
            z = list(z)
            for slot, (c, start, count, wgt, r1, r2, r3, r4) in enumerate(per):
                on = ok & (j < count)
                at = start + j
                val = dr.gather(b.Float, self.values, at, on)
                i = [dr.gather(b.UInt, self.index, at * 4 + q, on) for q in range(4)]
                u1 = dr.gather(b.Float, d1, r1 + i[0], on)
                u2 = dr.gather(b.Float, d2, r2 + i[1], on)
                m3 = [dr.gather(b.Float, d3, row + i[2], on) for row in r3]
                m4 = [dr.gather(b.Float, d4, row + i[3], on) for row in r4]
                if value:  # z[channel, tap, a, b]: every bin pair of the tap on its own
                    spatial = val * u1 * u2
                    for a, ma in enumerate(m3):
                        sa = spatial * ma
                        for bb, mb in enumerate(m4):
                            z[slot * bins + a * len(m4) + bb] = dr.fma(sa, mb, z[slot * bins + a * len(m4) + bb])
                    continue
                u3 = None
                for g, a in zip(m3, lw):
                    u3 = g * a if u3 is None else u3 + g * a
                u4 = None
                for g, a in zip(m4, vw):
                    u4 = g * a if u4 is None else u4 + g * a
                z[c] = dr.fma(wgt, val * u1 * u2 * u3 * u4, z[c])
            return (j + 1, *z)

        size = len(per) * bins if value else 3
        state = dr.while_loop(state=(b.UInt(0), *(b.Float(0.0) for _ in range(size))),
                              cond=lambda j, *z: ok & (j < t), body=body)
        z = list(state[1:])
        out = self._value_rgb(z, taps, li, lw, vi, vw, ok) if value else self._coefficient_rgb(z, li, lw, vi, vw, ok)
        return dr.select(ok, b.Array3f(*out), 0.0)

    def _cell(self, a, bb, ok) -> tuple[list, list]:
        """Mean and std (3 Floats each) of the angular image of light bin a and view bin bb."""
        import drjit as dr

        b, cell = self.backend, (a * self.n_view + bb) * 3
        return ([dr.gather(b.Float, self.mean, cell + c, ok) for c in range(3)],
                [dr.gather(b.Float, self.std, cell + c, ok) for c in range(3)])

    def _rgb(self, yuv: list) -> list:
        """`model_space_to_rgb`: max(exp(YUV_TO_RGB yuv) - eps, 0)."""
        import drjit as dr

        return [dr.maximum(dr.exp(yuv[0] * row[0] + yuv[1] * row[1] + yuv[2] * row[2]) - self.eps, 0.0)
                for row in YUV_TO_RGB.tolist()]

    def _coefficient_rgb(self, z, li, lw, vi, vw, ok) -> list:
        """"coefficient": the bin-interpolated statistics standardise the interpolated z, then RGB."""
        import drjit as dr

        b = self.backend
        mean, std = [b.Float(0.0)] * 3, [b.Float(0.0)] * 3
        for a, wa in zip(li, lw):
            for bb, wb in zip(vi, vw):
                wgt = wa * wb
                m, d = self._cell(a, bb, ok)
                for c in range(3):
                    mean[c] = dr.fma(m[c], wgt, mean[c])
                    std[c] = dr.fma(d[c], wgt, std[c])
        return self._rgb([dr.fma(z[c], std[c], mean[c]) for c in range(3)])

    def _value_rgb(self, z, taps, li, lw, vi, vw, ok) -> list:
        """"value": every tap and bin pair standardised with its own bin's statistics and taken to RGB, then the
        RGB values weighted (tap weight x light weight x view weight) and summed."""
        import drjit as dr

        b, n_taps, bins = self.backend, len(taps), len(li) * len(vi)
        out = [b.Float(0.0)] * 3
        for a, (la, wa) in enumerate(zip(li, lw)):
            for bb, (vb, wb) in enumerate(zip(vi, vw)):
                mean, std = self._cell(la, vb, ok)
                for tap, (*_, wt) in enumerate(taps):
                    at = tap * bins + a * len(vi) + bb
                    rgb = self._rgb([dr.fma(z[(c * n_taps) * bins + at], std[c], mean[c]) for c in range(3)])
                    wgt = wt * wa * wb
                    out = [dr.fma(wgt, v, o) for v, o in zip(rgb, out)]
        return out


PROGRAMS["sparse-btf"] = SparseBtf
