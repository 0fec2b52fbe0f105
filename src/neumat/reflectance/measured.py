"""Measured BRDFs as Materials: MERL tables (reference lookup) and RGL files (Mitsuba `measured` plugin).

`MerlMaterial` follows `BRDFRead.cpp` (Matusik et al. 2003): Rusinkiewicz angles, theta_half cell
sqrt(theta_h / (pi/2)) * 90, theta_diff cell theta_d / (pi/2) * 90, phi_diff folded to [0, pi) by
reciprocity with 180 cells; cell i covers [i, i + 1) in these coordinates (phi_d = pi exactly, e.g.
wi on the normal, falls in cell 0, the reference's cell 179 or 0 depending on the sign of a zero).

`RglMaterial` reproduces `src/bsdfs/measured.cpp` of Mitsuba 3 (Dupuy & Jakob 2018): the half vector is
mapped to the unit square, the VNDF warp is inverted to get the sample coordinates, the `rgb` table is
interpolated there and multiplied by ndf / (4 sigma). Argument order: `q.wi` plays the plugin's `si.wi`
(the direction the tables are conditioned on) and `q.wo` its `wo`; the plugin returns BRDF * cos(theta_o),
we divide by cos(theta_o). The data is not exactly reciprocal (about 1 % median difference when wi and wo
are swapped), so this order matters slightly. Small negative values of the data are kept, as Mitsuba does.
Sampling follows the plugin (luminance warp, then VNDF warp, then reflection about the half vector).
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import torch

from ..core.coords import io_to_rusinkiewicz
from ..core.errors import InputError
from ..core.material import Material, check_sample_u, sample_weight, upper_hemisphere, zero_below_horizon
from ..core.query import Query, Sample
from ..io.merl import MERL_DIMS, MERL_SCALE, read_merl
from ..io.rgl import RglData, read_rgl
from ..nn import cpu_kernels


class MerlMaterial(Material):
    """A MERL table as a Material.

    table:       unscaled (3, 90, 90, 180) array (R, G, B), as stored in a `.binary` file.
    interpolate: False: nearest cell as the reference code; True: trilinear between cell centres
                 (phi_diff periodic with period pi, theta clamped to the first / last centre).
    """

    can_sample = False

    def __init__(self, table, interpolate: bool = False, name: str = "merl") -> None:
        t = torch.as_tensor(np.asarray(table, dtype=np.float64))
        if t.shape != (3, *MERL_DIMS):
            raise InputError(f"MerlMaterial table: expected shape (3, 90, 90, 180), got {tuple(t.shape)}")
        scale = torch.tensor(MERL_SCALE, dtype=torch.float64).view(3, 1, 1, 1)
        #: scaled, clamped values (90 * 90 * 180, 3); negative entries (missing) become 0
        self.values = (t * scale).clamp(min=0).reshape(3, -1).T.contiguous()
        self.interpolate = interpolate
        self.name = name
        self._cache: dict = {}

    @classmethod
    def from_file(cls, path: str | Path, interpolate: bool = False) -> "MerlMaterial":
        """Read a MERL `.binary` file."""
        return cls(read_merl(path).table, interpolate=interpolate, name=Path(path).stem)

    def _values(self, device, dtype) -> torch.Tensor:
        key = (str(device), dtype)
        if key not in self._cache:
            self._cache = {key: self.values.to(device=device, dtype=dtype)}
        return self._cache[key]

    def eval(self, q: Query) -> torch.Tensor:
        """BRDF (N, 3); 0 where either direction is below the surface."""
        q.require("wo", who="MerlMaterial")
        theta_h, _, theta_d, phi_d = io_to_rusinkiewicz(q.wi, q.wo)
        phi_d = torch.where(phi_d >= math.pi, phi_d - math.pi, phi_d)
        x_h = torch.sqrt(theta_h.clamp(min=0) / (math.pi / 2)) * MERL_DIMS[0]
        x_d = theta_d / (math.pi / 2) * MERL_DIMS[1]
        x_p = phi_d / math.pi * MERL_DIMS[2]
        vals = self._values(q.device, q.dtype)
        if self.interpolate:
            f = self._trilinear(vals, x_h, x_d, x_p)
        else:
            i_h = x_h.long().clamp(0, MERL_DIMS[0] - 1)
            i_d = x_d.long().clamp(0, MERL_DIMS[1] - 1)
            i_p = x_p.long().clamp(0, MERL_DIMS[2] - 1)
            f = vals[(i_h * MERL_DIMS[1] + i_d) * MERL_DIMS[2] + i_p]
        return zero_below_horizon(f, q.wi, q.wo)

    @staticmethod
    def _trilinear(vals: torch.Tensor, x_h, x_d, x_p) -> torch.Tensor:
        n_h, n_d, n_p = MERL_DIMS
        idx, wts = [], []
        for x, n, periodic in ((x_h, n_h, False), (x_d, n_d, False), (x_p, n_p, True)):
            c = x - 0.5
            c = torch.remainder(c, n) if periodic else c.clamp(0, n - 1)
            i0 = c.floor().long().clamp(0, n - 1)
            t = c - i0.to(c.dtype)
            i1 = (i0 + 1) % n if periodic else (i0 + 1).clamp(max=n - 1)
            idx.append((i0, i1))
            wts.append((1 - t, t))
        f = 0
        for a in range(2):
            for b in range(2):
                for c in range(2):
                    lin = (idx[0][a] * n_d + idx[1][b]) * n_p + idx[2][c]
                    f = f + (wts[0][a] * wts[1][b] * wts[2][c]).unsqueeze(-1) * vals[lin]
        return f

    def describe(self) -> str:
        return f"{self.name} (MERL {'trilinear' if self.interpolate else 'nearest'})"


class Marginal2D:
    """Torch port of Mitsuba's continuous `Marginal2D`: a bilinear 2D density on [0, 1]^2 of resolution
    (H, W), conditioned on parameters by linear interpolation between slices.

    data:         (*param_sizes, H, W) or, for `eval` only, (*param_sizes, K, H, W) with K channels.
    param_values: one sorted 1D array per parameter dimension.
    normalize:    scale each slice so that its bilinear interpolant integrates to 1 (needed for warping).
    Positions are (x, y) with x along W. Tables are float32 as in Mitsuba; CDFs are built in float64.
    """

    def __init__(self, data: np.ndarray, param_values: list[np.ndarray], normalize: bool = True,
                 channels: bool = False, sampling: bool = True) -> None:
        data = np.asarray(data, dtype=np.float64)
        n_par = len(param_values)
        self.param_values = [torch.as_tensor(np.asarray(p, dtype=np.float64)) for p in param_values]
        self.param_sizes = tuple(data.shape[:n_par])
        self.h, self.w = data.shape[-2:]
        k = data.shape[n_par] if channels else 1
        slices = data.reshape(-1, k, self.h, self.w)
        if normalize:
            rows = 0.5 / (self.w - 1) * (slices[..., :-1] + slices[..., 1:]).sum(-1)
            total = 0.5 / (self.h - 1) * (rows[..., :-1] + rows[..., 1:]).sum(-1)
            slices = slices / total[..., None, None]
        flat = slices.astype(np.float32).reshape(slices.shape[0], k, -1)
        self.data = torch.as_tensor(flat.transpose(0, 2, 1).copy())  # (S, H * W, K)
        if sampling:
            s = slices[:, 0]
            cond = np.cumsum(0.5 / (self.w - 1) * (s[..., :-1] + s[..., 1:]), -1)  # (S, H, W-1)
            marg = np.cumsum(0.5 / (self.h - 1) * (cond[:, :-1, -1] + cond[:, 1:, -1]), -1)  # (S, H-1)
            self.cond = torch.as_tensor(cond.astype(np.float32)).reshape(cond.shape[0], -1)
            self.marg = torch.as_tensor(marg.astype(np.float32))
        self._cache: dict = {}

    def _tables(self, device, dtype) -> dict:
        key = (str(device), dtype)
        if key not in self._cache:
            names = ("data", "cond", "marg")
            self._cache[key] = {n: getattr(self, n).to(device=device, dtype=dtype) for n in names if hasattr(self, n)}
            self._cache[key]["params"] = [p.to(device=device, dtype=dtype) for p in self.param_values]
            # flat offsets (4, 1) of a patch's corners (ix, iy), (ix + 1, iy), (ix, iy + 1), (ix + 1, iy + 1)
            self._cache[key]["corners"] = torch.tensor([[0], [1], [self.w], [self.w + 1]], device=device)
            data = self._cache[key]["data"]                         # (S, H * W, K)
            self._cache[key]["channels"] = [data[..., k].contiguous().view(-1) for k in range(data.shape[2])]
        return self._cache[key]

    def _slices(self, params: list[torch.Tensor], tabs: dict) -> tuple[torch.Tensor, torch.Tensor]:
        """Slice indices (C, N) and weights (C, N) of the 2^D neighbouring parameter slices (parameters with one
        slice count once: their second neighbour would have weight 0). Slices outermost: each slice's weight then
        multiplies a contiguous block of gathered values."""
        n = params[0].shape[0] if params else 1
        ref = params[0] if params else tabs["data"]
        idx = torch.zeros(1, n, dtype=torch.long, device=ref.device)
        wts = torch.ones(1, n, dtype=ref.dtype, device=ref.device)
        for d, (p, vals) in enumerate(zip(params, tabs["params"])):
            size = vals.shape[0]
            if size == 1:  # one slice along this parameter (an isotropic file's phi_i): nothing to interpolate
                continue
            stride = int(np.prod(self.param_sizes[d + 1:], dtype=np.int64))
            i0 = (torch.searchsorted(vals, p.contiguous()).clamp(1, size - 1) - 1)
            i1 = i0 + 1
            w1 = ((p - vals[i0]) / (vals[i1] - vals[i0])).clamp(0, 1)
            idx = torch.cat([idx + i0 * stride, idx + i1 * stride], 0)
            wts = torch.cat([wts * (1 - w1), wts * w1], 0)
        return idx, wts

    def slices(self, params: list[torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
        """`_slices` of parameters (each (N,)), for `eval` / `invert` calls of tables on the same parameter grid."""
        return self._slices(params, self._tables(params[0].device, params[0].dtype))

    @staticmethod
    def _lookup(table: torch.Tensor, sl: torch.Tensor, wts: torch.Tensor, i: torch.Tensor) -> torch.Tensor:
        """Parameter-interpolated table[:, i] for a (S, M) table and flat indices i (N,) or (N, J) -> (N,) or
        (N, J): one flat gather of every (slice, index) pair, then the weighted sum over the slices."""
        rows = sl * table.shape[1]                                  # (C, N) offsets of the slices
        if i.dim() == 1:
            return (torch.take(table, rows + i) * wts).sum(0)
        return (torch.take(table, rows[:, :, None] + i) * wts[:, :, None]).sum(0)

    def _corners(self, pos, sl, wts, tabs):
        """Patch (ix, iy), position inside it (fx, fy) and the four corner values of points pos (N, 2)."""
        pos = torch.nan_to_num(pos, nan=0.0)  # a NaN position would become a wild index
        x = pos[:, 0].clamp(0, 1) * (self.w - 1)
        y = pos[:, 1].clamp(0, 1) * (self.h - 1)
        ix = x.long().clamp(max=self.w - 2)
        iy = y.long().clamp(max=self.h - 2)
        return ix, iy, x - ix.to(x.dtype), y - iy.to(y.dtype), self._patch(ix, iy, sl, wts, tabs)

    def _patch(self, ix, iy, sl, wts, tabs) -> list[torch.Tensor]:
        """Values (K, N) (channels first) at the corners (ix, iy), (ix + 1, iy), (ix, iy + 1), (ix + 1, iy + 1)."""
        channels = tabs["channels"]                                 # K x (S * H * W), one table per channel
        corner = (iy * self.w + ix)[None, :] + tabs["corners"]     # (4, N) flat corner cells
        # (C, 4, N) flat indices, queries innermost: the slice weights (C, 1, N) multiply contiguous rows
        rows = (sl * (self.h * self.w))[:, None, :] + corner
        vals = []
        for table in channels:
            v = torch.take(table, rows)
            vals.append(v[0] if sl.shape[0] == 1 else (v * wts[:, None, :]).sum(0))  # one slice: weight 1
        return list(torch.stack(vals, 1).unbind(0))

    def eval(self, pos: torch.Tensor, params: list[torch.Tensor], slices=None) -> torch.Tensor:
        """Bilinear value at pos (N, 2) for parameters (each (N,)): (N, K). slices: `slices(params)` if known."""
        tabs = self._tables(pos.device, pos.dtype)
        sl, wts = slices or self._slices(params, tabs)
        _, _, fx, fy, (v00, v10, v01, v11) = self._corners(pos, sl, wts, tabs)
        return torch.lerp(torch.lerp(v00, v10, fx), torch.lerp(v01, v11, fx), fy).t()  # (K, N) -> (N, K)

    def invert(self, pos: torch.Tensor, params: list[torch.Tensor], slices=None) -> tuple[torch.Tensor, torch.Tensor]:
        """Inverse of `sample`: uniform coordinates (N, 2) of warped points pos (N, 2), and the density (N,).
        slices: `slices(params)` if known."""
        tabs = self._tables(pos.device, pos.dtype)
        sl, wts = slices or self._slices(params, tabs)
        ix, iy, fx, fy, (v00, v10, v01, v11) = self._corners(pos, sl, wts, tabs)
        v00, v10, v01, v11 = v00[0], v10[0], v01[0], v11[0]
        c0, c1 = torch.lerp(v00, v01, fy), torch.lerp(v10, v11, fy)
        pdf = torch.lerp(c0, c1, fx)
        sx = fx * torch.lerp(c0, c1, 0.5 * fx) / (self.w - 1)
        cond, wm = tabs["cond"], self.w - 1
        row0 = iy * wm
        prev = (ix - 1).clamp(min=0)
        # the conditional CDF before column ix and at the row's end, on rows iy and iy + 1: one gather
        c = self._lookup(cond, sl, wts,
                         torch.stack([row0 + prev, row0 + wm + prev, row0 + wm - 1, row0 + 2 * wm - 1], 1))
        b0, b1, r0, r1 = c.unbind(1)
        before = torch.lerp(b0, b1, fy)
        sx = sx + torch.where(ix > 0, before, torch.zeros_like(before))
        sx = sx / torch.lerp(r0, r1, fy)
        sy = fy * torch.lerp(r0, r1, 0.5 * fy) / (self.h - 1)
        m_prev = self._lookup(tabs["marg"], sl, wts, (iy - 1).clamp(min=0))
        sy = sy + torch.where(iy > 0, m_prev, torch.zeros_like(m_prev))
        return torch.stack([sx, sy], -1), pdf

    def sample(self, u: torch.Tensor, params: list[torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
        """Warp uniform u (N, 2) to the density: points (N, 2) in [0, 1]^2 and their density (N,)."""
        tabs = self._tables(u.device, u.dtype)
        sl, wts = self._slices(params, tabs)
        eps = 2.0 ** -24
        u = u.clamp(eps, 1 - eps)
        ux, uy = u[:, 0], u[:, 1]
        marg = (tabs["marg"][sl] * wts[:, :, None]).sum(0)  # (N, H-1)
        row = torch.searchsorted(marg, uy[:, None].contiguous()).squeeze(1).clamp(max=self.h - 2)
        m_prev = marg.gather(1, (row - 1).clamp(min=0)[:, None]).squeeze(1)
        uy = uy - torch.where(row > 0, m_prev, torch.zeros_like(m_prev))
        wm = self.w - 1
        cond = tabs["cond"].view(-1, self.h, wm)
        rows = [(cond[sl, row + o] * wts[:, :, None]).sum(0) for o in (0, 1)]  # (N, W-1) each
        r0, r1 = rows[0][:, -1], rows[1][:, -1]
        fy = _sample_segment(uy, self.h - 1, r0, r1)
        ux = ux * torch.lerp(r0, r1, fy)
        cdf = torch.lerp(rows[0], rows[1], fy[:, None])
        col = torch.searchsorted(cdf, ux[:, None].contiguous()).squeeze(1).clamp(max=self.w - 2)
        c_prev = cdf.gather(1, (col - 1).clamp(min=0)[:, None]).squeeze(1)
        ux = ux - torch.where(col > 0, c_prev, torch.zeros_like(c_prev))
        v00, v10, v01, v11 = self._patch(col, row, sl, wts, tabs)
        c0 = torch.lerp(v00[0], v01[0], fy)
        c1 = torch.lerp(v10[0], v11[0], fy)
        fx = _sample_segment(ux, wm, c0, c1)
        out = torch.stack([(col.to(u.dtype) + fx) / wm, (row.to(u.dtype) + fy) / (self.h - 1)], -1)
        return out, torch.lerp(c0, c1, fx)


def _sample_segment(s: torch.Tensor, inv_width: float, v0: torch.Tensor, v1: torch.Tensor) -> torch.Tensor:
    """Position t in [0, 1] where the integral of lerp(v0, v1, .) over [0, t] / inv_width reaches s."""
    non_const = (v0 - v1).abs() > 1e-4 * (v0 + v1)
    s = s * 2 * inv_width
    quad = v0 - torch.sqrt((v0 * v0 + s * (v1 - v0)).clamp(min=0))
    s = torch.where(non_const, quad, s)
    div = torch.where(non_const, v0 - v1, v0 + v1)
    return torch.where(div != 0, s / torch.where(div != 0, div, torch.ones_like(div)), s)


def _above(wi: torch.Tensor, wo: torch.Tensor, active: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """wi, wo (N, 3) with the pairs that are not `active` (a direction below the horizon, whose value is 0)
    replaced by the normal, so that no table is looked up outside its domain."""
    normal = torch.zeros_like(wi)
    normal[:, 2] = 1
    keep = active[:, None]
    return torch.where(keep, wi, normal), torch.where(keep, wo, normal)


def _elevation(d: torch.Tensor) -> torch.Tensor:
    """theta of unit vectors (N, 3), computed stably as 2 asin(|d - z| / 2) (as Mitsuba)."""
    dist = torch.sqrt(d[:, 0] ** 2 + d[:, 1] ** 2 + (d[:, 2] - 1) ** 2)
    return 2 * torch.asin((0.5 * dist).clamp(-1, 1))


def _theta2u(theta):
    return torch.sqrt(theta * (2 / math.pi))


def _phi2u(phi):
    return (phi + math.pi) / (2 * math.pi)


def _mulsign_neg(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """a * -sign(b), with the sign bit deciding (Dr.Jit `mulsign_neg`)."""
    return torch.where(torch.signbit(b), a, -a)


class RglMaterial(Material):
    """An RGL measured BRDF (`*_rgb.bsdf`), evaluated and sampled as Mitsuba 3's `measured` plugin."""

    can_sample = True

    def __init__(self, data: RglData, name: str = "rgl") -> None:
        f = data.fields
        self.name = name
        self.description = data.description
        self.isotropic = data.isotropic
        self.jacobian = bool(f["jacobian"][0])
        phi_i = f["phi_i"].astype(np.float64)
        self.reduction = 0 if self.isotropic else int(round(2 * math.pi / float(phi_i[-1] - phi_i[0])))
        params = [f["phi_i"], f["theta_i"]]
        self.ndf = Marginal2D(f["ndf"], [], normalize=False, sampling=False)
        self.sigma = Marginal2D(f["sigma"], [], normalize=False, sampling=False)
        self.vndf = Marginal2D(f["vndf"], params)
        self.luminance = Marginal2D(f["luminance"], params)
        self.rgb = Marginal2D(f["rgb"], params, normalize=False, channels=True, sampling=False)

    @classmethod
    def from_file(cls, path: str | Path) -> "RglMaterial":
        """Read an RGL `*_rgb.bsdf` file."""
        return cls(read_rgl(path), name=Path(path).stem)

    def _reduce(self, wi: torch.Tensor, *others: torch.Tensor):
        """Fold directions into the measured azimuth range of anisotropic files; returns the signs too."""
        if self.reduction < 2:
            return (wi, *others), None
        sy = wi[:, 1]
        sx = wi[:, 0] if self.reduction == 4 else sy
        flip = lambda v: torch.stack([_mulsign_neg(v[:, 0], sx), _mulsign_neg(v[:, 1], sy), v[:, 2]], -1)
        return (flip(wi), *(flip(v) for v in others)), (sx, sy)

    def _angles(self, wi: torch.Tensor, m: torch.Tensor):
        theta_i = _elevation(wi)
        phi_i = torch.atan2(wi[:, 1], wi[:, 0])
        theta_m = _elevation(m)
        phi_m = torch.atan2(m[:, 1], m[:, 0])
        u_m = torch.stack([_theta2u(theta_m), _phi2u(phi_m - phi_i if self.isotropic else phi_m)], -1)
        u_m = torch.stack([u_m[:, 0], u_m[:, 1] - torch.floor(u_m[:, 1])], -1)
        u_wi = torch.stack([_theta2u(theta_i), _phi2u(phi_i)], -1)
        return [phi_i, theta_i], u_m, u_wi

    def _spectrum(self, sample, params, u_m, u_wi, slices=None) -> torch.Tensor:
        spec = self.rgb.eval(sample, params, slices)
        if self.jacobian:
            spec = spec * (self.ndf.eval(u_m, []) / (4 * self.sigma.eval(u_wi, [])))
        return spec

    def eval_cos(self, q: Query) -> torch.Tensor:
        """The plugin's value BRDF * cos(theta_o), (N, 3)."""
        q.require("wo", who="RglMaterial")
        active = upper_hemisphere(q.wi, q.wo)
        (wi, wo), _ = self._reduce(*_above(q.wi, q.wo, active))
        m = wi + wo
        m = m / m.norm(dim=-1, keepdim=True).clamp(min=1e-30)
        params, u_m, u_wi = self._angles(wi, m)
        slices = self.vndf.slices(params)  # vndf and rgb share the (phi_i, theta_i) grid
        sample, _ = self.vndf.invert(u_m, params, slices)
        spec = self._spectrum(sample, params, u_m, u_wi, slices)
        return torch.where(active[:, None], spec, torch.zeros_like(spec))

    def eval(self, q: Query) -> torch.Tensor:
        """BRDF (N, 3): the plugin value divided by cos(theta_o); 0 below the surface. Without autograd, in float32
        on the CPU, one fused C call (`neumat.nn.cpu_kernels.rgl_eval`; the torch path's values within float32
        rounding): the torch path is some 150 small tensor operations and gathers."""
        q.require("wo", who="RglMaterial")
        if cpu_kernels.usable(q.wi, q.wo):
            return cpu_kernels.rgl_eval(cpu_kernels.rgl_tables(self), q.wi, q.wo)
        f = self.eval_cos(q)
        cos_o = q.wo[:, 2:3]
        return torch.where(cos_o > 0, f / torch.where(cos_o > 0, cos_o, torch.ones_like(cos_o)), torch.zeros_like(f))

    def pdf(self, q: Query) -> torch.Tensor:
        """Solid-angle density (N,) of `sample` (luminance warp, then VNDF warp, then reflection)."""
        q.require("wo", who="RglMaterial")
        active = upper_hemisphere(q.wi, q.wo)
        (wi, wo), _ = self._reduce(*_above(q.wi, q.wo, active))
        m = wi + wo
        m = m / m.norm(dim=-1, keepdim=True).clamp(min=1e-30)
        params, u_m, _ = self._angles(wi, m)
        slices = self.vndf.slices(params)  # vndf and luminance share the (phi_i, theta_i) grid
        sample, vndf_pdf = self.vndf.invert(u_m, params, slices)
        lum_pdf = self.luminance.eval(sample, params, slices)[:, 0]
        sin_m = torch.sqrt((1 - m[:, 2] ** 2).clamp(min=0))
        jac = (2 * math.pi ** 2 * u_m[:, 0] * sin_m).clamp(min=1e-6) * 4 * (wi * m).sum(-1)
        pdf = vndf_pdf * lum_pdf / jac
        return torch.where(active, pdf, torch.zeros_like(pdf))

    def sample(self, q: Query, u: torch.Tensor) -> Sample:
        """Sample wo given q.wi and u (N, 2) in [0, 1)^2."""
        u = check_sample_u(q, u)
        (wi,), signs = self._reduce(q.wi)
        theta_i = _elevation(wi)
        phi_i = torch.atan2(wi[:, 1], wi[:, 0])
        params = [phi_i, theta_i]
        s, lum_pdf = self.luminance.sample(torch.stack([u[:, 1], u[:, 0]], -1), params)
        u_m, ndf_pdf = self.vndf.sample(s, params)
        phi_m = (2 * u_m[:, 1] - 1) * math.pi
        theta_m = u_m[:, 0] ** 2 * (math.pi / 2)
        if self.isotropic:
            phi_m = phi_m + phi_i
        st = torch.sin(theta_m)
        m = torch.stack([torch.cos(phi_m) * st, torch.sin(phi_m) * st, torch.cos(theta_m)], -1)
        dot = (wi * m).sum(-1)
        jac = (2 * math.pi ** 2 * u_m[:, 0] * st).clamp(min=1e-6) * 4 * dot
        wo = 2 * dot[:, None] * m - wi
        if signs is not None:
            sx, sy = signs
            wo = torch.stack([_mulsign_neg(wo[:, 0], sx), _mulsign_neg(wo[:, 1], sy), wo[:, 2]], -1)
        wo = wo / wo.norm(dim=-1, keepdim=True)
        pdf = ndf_pdf * lum_pdf / jac
        valid = (q.wi[:, 2] > 0) & (wo[:, 2] > 0) & (pdf > 0) & torch.isfinite(pdf)
        pdf = torch.where(valid, pdf, torch.zeros_like(pdf))
        wo_safe = torch.where(valid[:, None], wo, q.wi)
        f = self.eval(q.with_wo(wo_safe))
        return Sample(wo=wo_safe, pdf=pdf, weight=sample_weight(f, wo_safe, pdf, valid))

    def describe(self) -> str:
        return f"{self.name} (RGL: {self.description})"
