"""Dr.Jit runtime program "healpix-grid-mlp" (imports no torch): the NeuBRDF forms that "healpix-mlp" (runtime.py)
does not cover, in one program: inverse-distance corner weights (`runtime_interpolation = "idw"`, shared-NeuBRDF's
default), a neural texture (T(uv) at the finest level, bilinear, wrap tiling) and several materials sharing one
codebook and MLP (shared-NeuBRDF: `select(i)`, or per lane `eval(..., material=UInt)`); uniform weights as
"healpix-mlp". S- is looked up at the pixel of the mirrored wo (x, y, -z); the MLP input order is the torch
model's: [psi(wi), psi(mirrored wo), T(uv), direction inputs].

Details (weights, arrays, what the footprint does): docs/formats/drjit.md, "healpix-grid-mlp".
"""
from __future__ import annotations

import numpy as np

from ...core.errors import DataFormatError, InputError
from .runtime import PROGRAMS, Backend, Mlp, Runtime, direction_inputs, mlp_layers, vec2pix

#: distances below this count as this (`neumat.nn.healpix.idw_weights`' eps)
IDW_EPS = 1e-7


class HealpixGridMlp(Runtime):
    """Program "healpix-grid-mlp" (module docstring). Manifest: nside, feature_dim, hidden, activation,
    direction_inputs, interpolation ("uniform" or "idw"), materials (t), material (the default one), texture_channels
    (C, 0: none), output "exp". Arrays: features (R, k); pixel_rows (t, 2, 12 nside^2, 4) feature rows of each
    pixel's 4 corners on S+ (by the pixel of wi) and S- (by the pixel of the mirrored wo), -1 where a corner is off
    the grid (pixels never looked up); idw: pixel_vertices (t, 2, 12 nside^2, 4) their vertex ids and vertex_dirs
    (V, 3); first_weight (hidden, 2 k + C + extra), first_bias; layer{i}_weight / layer{i}_bias from 1; texture:
    texture0 (C, H, W) (further levels texture1, ... are kept in the export, not read)."""

    def __init__(self, manifest: dict, arrays: dict, backend: Backend, compute: str,
                 mlp_form: str | None = None) -> None:
        super().__init__(manifest, backend, compute, mlp_form)
        import drjit as dr

        b = backend
        self.nside = n = int(manifest["nside"])
        k, hidden = int(manifest["feature_dim"]), int(manifest["hidden"])
        self.kind = manifest.get("direction_inputs", "none")
        extra = {"none": 0, "hd": 6, "hd_warp": 6}.get(self.kind)
        self.interpolation = manifest.get("interpolation", "uniform")
        self.materials = int(manifest.get("materials", 1))
        c = int(manifest.get("texture_channels", 0))
        if extra is None or self.interpolation not in ("uniform", "idw") or self.materials < 1 or c < 0:
            raise DataFormatError(f"drjit export ({self.describe()}): unknown direction_inputs / interpolation / "
                                  "materials / texture_channels")
        self.pixels = p = 12 * n * n
        self.hidden, self.k = hidden, k
        feats = arrays["features"].astype(np.float32)
        rows = arrays["pixel_rows"].astype(np.int64)
        w1 = arrays["first_weight"].astype(np.float32)
        bias = arrays["first_bias"].astype(np.float32)
        if rows.shape != (self.materials, 2, p, 4) or feats.ndim != 2 or feats.shape[1] != k or \
                w1.shape != (hidden, 2 * k + c + extra) or rows.max(initial=-1) >= len(feats):
            raise DataFormatError(f"drjit export ({self.describe()}): array shapes do not match the manifest")
        w_i, w_o = w1[:, :k], w1[:, k:2 * k]
        if self.interpolation == "uniform":
            # per (material, side, pixel): the mean corner feature times W_i (+ b) or W_o; two rows sum to layer 1
            padded = np.concatenate([feats, np.zeros((1, k), np.float32)])
            mean = padded[np.where(rows < 0, len(feats), rows)].mean(3, dtype=np.float32)
            mean[(rows < 0).any(-1)] = 0.0
            table = np.stack([mean[:, 0] @ w_i.T + bias, mean[:, 1] @ w_o.T], 1).astype(np.float32)
            self.table = b.Float(np.ascontiguousarray(table).ravel())
            dr.eval(self.table)
        else:
            # per feature row: W_i f (rows 0 .. R-1) and W_o f (rows R .. 2R-1); per pixel corner rows and vertices
            vid = arrays["pixel_vertices"].astype(np.int64)
            dirs = arrays["vertex_dirs"].astype(np.float32)
            if vid.shape != rows.shape or dirs.ndim != 2 or dirs.shape[1] != 3 or vid.max(initial=0) >= len(dirs):
                raise DataFormatError(f"drjit export ({self.describe()}): pixel_vertices / vertex_dirs do not match")
            table = np.concatenate([feats @ w_i.T, feats @ w_o.T]).astype(np.float32)
            self.table = b.Float(np.ascontiguousarray(table).ravel())
            side = np.array([0, len(feats)], np.int64).reshape(1, 2, 1, 1)
            self.rows = b.UInt(np.ascontiguousarray(np.where(rows < 0, 0, rows + side), np.uint32).ravel())
            self.vertices = b.UInt(np.ascontiguousarray(np.where(vid < 0, 0, vid), np.uint32).ravel())
            self.dirs = b.Float(np.ascontiguousarray(dirs).ravel())
            self.bias = bias.tolist()
            dr.eval(self.table, self.rows, self.vertices, self.dirs)
        self.texture = None
        if c:
            from .latent import Pyramid

            levels, i = [], 0
            while f"texture{i}" in arrays:
                levels.append(arrays[f"texture{i}"].astype(np.float32))
                i += 1
            if not levels or levels[0].ndim != 3 or levels[0].shape[0] != c:
                raise DataFormatError(f"drjit export ({self.describe()}): texture0 (C, H, W) missing or of other C")
            self.texture = Pyramid(b, levels[:1], 1)
            self.tex_first = Mlp(b, [(w1[:, 2 * k:2 * k + c], None)], manifest["activation"], compute, mlp_form)
            self.spatially_varying = True
        self.mlp = Mlp(b, mlp_layers(arrays, first=1), manifest["activation"], compute, mlp_form)
        self.hd = Mlp(b, [(w1[:, 2 * k + c:], None)], manifest["activation"], compute, mlp_form) if extra else None
        self.material = 0
        self.select(int(manifest.get("material", 0)))

    def select(self, material: int) -> "HealpixGridMlp":
        """Make material `material` (0 .. materials - 1) the one `eval` reads by default; returns self."""
        if isinstance(material, bool) or not isinstance(material, (int, np.integer)) or \
                not 0 <= int(material) < self.materials:
            raise InputError(f"drjit runtime ({self.describe()}): material index: expected an integer in "
                             f"[0, {self.materials}), got {material!r}")
        self.material = int(material)
        return self

    def _idw(self, base, x, y, z, ok) -> list:
        """sum_c w_c table[row_c] (hidden Floats) over the 4 corners of pixel row `base` (UInt) for the looked-up
        direction (x, y, z), w_c its normalised inverse great-circle distances to the corner vertices."""
        import drjit as dr

        b = self.backend
        cols, weights = [], []
        for corner in range(4):
            at = base * 4 + corner
            v = dr.gather(b.UInt, self.vertices, at, ok)
            cols.append(dr.gather(b.UInt, self.rows, at, ok))
            vx, vy, vz = (dr.gather(b.Float, self.dirs, v * 3 + j, ok) for j in range(3))
            cx, cy, cz = y * vz - z * vy, z * vx - x * vz, x * vy - y * vx
            d = dr.atan2(dr.sqrt(cx * cx + cy * cy + cz * cz), x * vx + y * vy + z * vz)
            weights.append(1 / dr.maximum(d, IDW_EPS))
        total = weights[0] + weights[1] + weights[2] + weights[3]
        weights = [w / total for w in weights]
        n = dr.width((base, ok))
        out = None
        for col, w in zip(cols, weights):
            r = dr.gather(b.ArrayXf, self.table, col, ok, shape=(self.hidden, n))
            out = [r[j] * w for j in range(self.hidden)] if out is None else \
                [dr.fma(r[j], w, out[j]) for j in range(self.hidden)]
        return out

    def eval(self, wi, wo, active=True, uv=None, footprint=None, material=None):
        import drjit as dr

        b = self.backend
        ok = b.Bool(active) & (wi[2] > 0) & (wo[2] > 0)
        pi = vec2pix(b, self.nside, wi[0], wi[1], wi[2])
        po = vec2pix(b, self.nside, wo[0], wo[1], -wo[2])  # S-: the pixel of the mirrored wo
        ok &= (pi >= 0) & (pi < self.pixels) & (po >= 0) & (po < self.pixels)
        m = b.UInt(self.material) if material is None else b.UInt(material)
        if material is not None:
            ok &= m < self.materials
        bi = (m * 2) * self.pixels + b.UInt(pi)
        bo = (m * 2 + 1) * self.pixels + b.UInt(po)
        if self.interpolation == "uniform":
            n = dr.width((bi, bo, ok))
            rows = [dr.gather(b.ArrayXf, self.table, at, ok, shape=(self.hidden, n)) for at in (bi, bo)]
            h = [rows[0][j] + rows[1][j] for j in range(self.hidden)]
        else:
            a = self._idw(bi, wi[0], wi[1], wi[2], ok)
            c = self._idw(bo, wo[0], wo[1], -wo[2], ok)
            h = [x + y + bj for x, y, bj in zip(a, c, self.bias)]
        if self.texture is not None:
            u, v = (b.Float(0.0), b.Float(0.0)) if uv is None else (b.Float(uv[0]), b.Float(uv[1]))
            z = self.texture.filter(u, v, None, ok)
            h = [x + t for x, t in zip(h, self.tex_first(z))]
        if self.hd is not None:
            h = [x + t for x, t in zip(h, self.hd(direction_inputs(self.kind, wi, wo)))]
        out = [dr.exp(v) for v in self.mlp(h, first_activation=True)]
        return dr.select(ok, b.Array3f(*out), 0.0)


PROGRAMS["healpix-grid-mlp"] = HealpixGridMlp
