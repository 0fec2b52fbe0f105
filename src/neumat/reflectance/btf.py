"""Tabulated bidirectional texture functions (BTFs) as a spatially varying `Material`.

A BTF table holds, for every light direction l, view direction v and texel (row, col), the linear RGB
*apparent BRDF* (reflected radiance divided by the irradiance of the light measured perpendicular to it and
by cos(theta_l) of the macro surface), so that values exclude the cosine like every neumat BRDF.

Layout: `data (L, V, H, W, 3)`; `light_dirs (L, 3)` and `view_dirs (V, 3)` unit vectors of the local
frame (z = macro normal). Texel (row i, col j) has its centre at uv = ((j + 0.5) / W, 1 - (i + 0.5) / H),
the texture-set convention of `neumat.io.texture_set` (u right, v up, row 0 at the top).

Details: docs/notes/reflectance.md, section `neumat.reflectance.btf`.
"""
from __future__ import annotations

import math
from pathlib import Path

import torch

from ..core.checks import check_directions, check_finite
from ..core.errors import DataFormatError, InputError
from ..core.material import Material, zero_below_horizon
from ..core.query import Query
from ..io.btf import BTFTable, read_btf_table
from ..io.ubo2014 import read_ubo2014_table

#: polar angles (degrees) and azimuth counts of the 151-direction hemispherical set used by default
#: (rings every 15 degrees, counts proportional to sin(theta); the same size as the UBO2014 set)
HEMI151_RINGS = ((0.0, 1), (15.0, 12), (30.0, 23), (45.0, 32), (60.0, 39), (75.0, 44))
#: the UBO2003 / UTIA 81-direction set (Sattler et al. 2003)
UBO81_RINGS = ((0.0, 1), (15.0, 6), (30.0, 12), (45.0, 18), (60.0, 20), (75.0, 24))
#: the nominal 151 directions of Bonn's Dome 1 (UBO2014), (theta_deg, count, azimuth offset_deg) per ring, as
#: btflib's `create_ubo_dome1_sampling.m` lists them; real files store their own measured directions
UBO151_RINGS = ((0.0, 1, 0.0), (11.0, 6, 15.0), (23.5, 12, 0.0), (30.0, 12, 15.0), (37.5, 12, 0.0),
                (45.0, 18, 0.0), (52.5, 18, 7.5), (60.0, 24, 0.0), (67.5, 24, 7.5), (75.0, 24, 0.0))


def ring_directions(rings, dtype=torch.float32, device=None) -> torch.Tensor:
    """Unit directions (D, 3) on rings [(theta_deg, count[, offset_deg]), ...]; ring azimuths
    phi = 2 pi j / count + offset."""
    out = []
    for theta_deg, count, *offset in rings:
        if count < 1 or not 0 <= theta_deg < 90:
            raise InputError(f"ring_directions: ring (theta={theta_deg}, count={count}) needs 0 <= theta < 90 "
                             "and count >= 1")
        t = math.radians(theta_deg)
        for j in range(int(count)):
            p = 2 * math.pi * j / count + math.radians(offset[0] if offset else 0.0)
            out.append((math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)))
    return torch.tensor(out, dtype=dtype, device=device)


def direction_set(spec: str | int, dtype=torch.float32, device=None) -> torch.Tensor:
    """A named hemispherical direction set (D, 3).

    "hemi151" (default size of UBO2014), "ubo151" (the nominal UBO2014 dome), "ubo81" (UBO2003), or
    "rings:<n_rings>x<step_deg>" such as "rings:3x30" (rings at 0, 30, 60 degrees with counts proportional to
    sin theta), or an int n giving a ring set of about n directions (rings every 15 degrees up to 75).
    """
    if spec == "hemi151":
        return ring_directions(HEMI151_RINGS, dtype, device)
    if spec == "ubo81":
        return ring_directions(UBO81_RINGS, dtype, device)
    if spec == "ubo151":
        return ring_directions(UBO151_RINGS, dtype, device)
    if isinstance(spec, int) or (isinstance(spec, str) and spec.isdigit()):
        n = int(spec)
        if n < 1:
            raise InputError(f"direction set: expected a positive count, got {n}")
        return ring_directions(_rings_for_count(n, 15.0, 6), dtype, device)
    if isinstance(spec, str) and spec.startswith("rings:"):
        try:
            n_rings, step = spec[6:].split("x")
            n_rings, step = int(n_rings), float(step)
        except ValueError:
            raise InputError(f"direction set {spec!r}: expected 'rings:<n_rings>x<step_deg>'") from None
        if not math.isfinite(step) or step <= 0:
            raise InputError(f"direction set {spec!r}: the ring step must be a positive number of degrees")
        if n_rings < 1 or (n_rings - 1) * step >= 90:
            raise InputError(f"direction set {spec!r}: rings must stay below 90 degrees")
        rings = [(0.0, 1)] + [(i * step, max(3, round(2 * math.pi * math.sin(math.radians(i * step))
                                                       / math.radians(step))))
                              for i in range(1, n_rings)]
        return ring_directions(rings, dtype, device)
    raise InputError(f"direction set {spec!r}: expected 'hemi151', 'ubo151', 'ubo81', 'rings:<n>x<deg>' or a count")


def _rings_for_count(n: int, step: float, n_rings: int) -> list[tuple[float, int]]:
    """Rings at 0, step, 2 step, ... whose counts (proportional to sin theta) sum to n."""
    if n == 1:
        return [(0.0, 1)]
    thetas = [i * step for i in range(1, n_rings)]
    s = [math.sin(math.radians(t)) for t in thetas]
    counts = [max(1, round((n - 1) * si / sum(s))) for si in s]
    counts[-1] += (n - 1) - sum(counts)
    return [(0.0, 1)] + [(t, c) for t, c in zip(thetas, counts) if c > 0]


def angular_weights(table_dirs: torch.Tensor, w: torch.Tensor, k: int = 3) -> tuple[torch.Tensor, torch.Tensor]:
    """Indices (N, k) of the k bins of `table_dirs (D, 3)` nearest to `w (N, 3)` and their normalised
    inverse-angular-distance weights (N, k) (an exact hit gets weight 1)."""
    k = min(k, table_dirs.shape[0])
    table = table_dirs.to(w)
    _, idx = (w @ table.T).topk(k, dim=-1)
    near = table[idx]                                                     # (N, k, 3)
    wk = w[:, None, :].expand_as(near)
    # atan2(|w x d|, w . d) stays accurate for tiny angles, where acos(w . d) does not
    angle = torch.atan2(torch.cross(wk, near, dim=-1).norm(dim=-1), (wk * near).sum(-1))
    inv = 1.0 / angle.clamp(min=1e-7)
    exact = angle <= 1e-7
    inv = torch.where(exact.any(-1, keepdim=True), exact.to(w.dtype), inv)
    return idx, inv / inv.sum(-1, keepdim=True)


def bilinear_taps(uv: torch.Tensor, height: int, width: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Rows (N, 4), cols (N, 4) and weights (N, 4) of the wrap-around bilinear lookup of uv (N, 2)."""
    x = uv[:, 0] * width - 0.5
    y = (1 - uv[:, 1]) * height - 0.5
    x0, y0 = torch.floor(x), torch.floor(y)
    fx, fy = x - x0, y - y0
    x0, y0 = x0.long(), y0.long()
    cols = torch.stack([x0, x0 + 1, x0, x0 + 1], -1) % width
    rows = torch.stack([y0, y0, y0 + 1, y0 + 1], -1) % height
    wts = torch.stack([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy], -1)
    return rows, cols, wts


class TabulatedBTF(Material):
    """A BTF table (see the module docstring) answering `Query(wi, wo, uv)`.

    data: (L, V, H, W, 3) apparent BRDF values, linear RGB; light_dirs (L, 3); view_dirs (V, 3).
    neighbours: k of the angular inverse-distance interpolation.
    """

    name = "btf"
    can_sample = False
    spatially_varying = True

    def __init__(self, data: torch.Tensor, light_dirs: torch.Tensor, view_dirs: torch.Tensor,
                 neighbours: int = 3, label: str = "btf") -> None:
        check_btf_arrays(data, light_dirs, view_dirs)
        if neighbours < 1:
            raise InputError(f"TabulatedBTF neighbours: expected >= 1, got {neighbours}")
        self.data = data
        self.light_dirs = light_dirs.to(data.device, torch.float32)
        self.view_dirs = view_dirs.to(data.device, torch.float32)
        self.neighbours = neighbours
        self.label = label

    @classmethod
    def from_table(cls, table: BTFTable, neighbours: int = 3) -> "TabulatedBTF":
        """The material of a `BTFTable` read by `neumat.io.btf` or `neumat.io.ubo2014`."""
        return cls(table.data, table.light_dirs, table.view_dirs, neighbours=neighbours, label=table.label)

    @property
    def shape(self) -> tuple[int, int, int, int]:
        """(L, V, H, W)."""
        return tuple(self.data.shape[:4])

    def eval(self, q: Query) -> torch.Tensor:
        q.require("uv", who="TabulatedBTF")
        n = len(q)
        dev = self.data.device
        wi, wo, uv = q.wi.to(dev, torch.float32), q.wo.to(dev, torch.float32), q.uv.to(dev, torch.float32)
        li, lw = angular_weights(self.light_dirs, wi, self.neighbours)
        vi, vw = angular_weights(self.view_dirs, wo, self.neighbours)
        rows, cols, sw = bilinear_taps(uv, self.data.shape[2], self.data.shape[3])
        # all (light, view, texel) combinations: (N, kl, kv, 4)
        idx_l = li[:, :, None, None].expand(n, li.shape[1], vi.shape[1], 4)
        idx_v = vi[:, None, :, None].expand_as(idx_l)
        idx_r = rows[:, None, None, :].expand_as(idx_l)
        idx_c = cols[:, None, None, :].expand_as(idx_l)
        vals = self.data[idx_l, idx_v, idx_r, idx_c].float()                  # (N, kl, kv, 4, 3)
        w = lw[:, :, None, None] * vw[:, None, :, None] * sw[:, None, None, :]
        f = (vals * w.unsqueeze(-1)).sum(dim=(1, 2, 3))
        f = zero_below_horizon(f, wi, wo)
        return f.to(q.wi.device, q.wi.dtype)

    def describe(self) -> str:
        l, v, h, w = self.shape
        return f"btf {self.label} ({h}x{w} texels, {l} light x {v} view directions)"


def check_btf_arrays(data: torch.Tensor, light_dirs: torch.Tensor, view_dirs: torch.Tensor,
                     where: str = "BTF") -> None:
    """Raise InputError unless data (L, V, H, W, 3) matches light_dirs (L, 3) and view_dirs (V, 3)."""
    if not isinstance(data, torch.Tensor) or data.dim() != 5 or data.shape[-1] != 3:
        got = tuple(data.shape) if isinstance(data, torch.Tensor) else type(data).__name__
        raise InputError(f"{where} data: expected shape (L, V, H, W, 3), got {got}")
    check_directions(light_dirs, f"{where} light directions")
    check_directions(view_dirs, f"{where} view directions")
    if light_dirs.shape[0] != data.shape[0]:
        raise InputError(f"{where}: {light_dirs.shape[0]} light directions but data has {data.shape[0]} light slices")
    if view_dirs.shape[0] != data.shape[1]:
        raise InputError(f"{where}: {view_dirs.shape[0]} view directions but data has {data.shape[1]} view slices")
    if bool((light_dirs[:, 2] <= 0).any()) or bool((view_dirs[:, 2] <= 0).any()):
        raise InputError(f"{where}: light and view directions must lie in the upper hemisphere (z > 0)")
    check_finite(data, f"{where} data")


def read_btf(path: str | Path, device=None, lights: list[int] | None = None, neighbours: int = 3) -> TabulatedBTF:
    """Read a `.nbtf` file (`neumat.io.btf`) as a float32 `TabulatedBTF` on `device` (optionally only some light
    slices)."""
    table = read_btf_table(path, device=device, lights=lights)
    try:
        return TabulatedBTF.from_table(table, neighbours=neighbours)
    except InputError as e:
        raise DataFormatError(f"{path}: {e}") from None


def read_ubo2014(path: str | Path, texels: tuple[int, int, int, int] | None = None, step: int = 1,
                 max_components: int | None = None, device=None, neighbours: int = 3,
                 max_gib: float = 8.0) -> TabulatedBTF:
    """A `TabulatedBTF` (L, V, h, w, 3) decoded from a Bonn `.btf` file (UBO2014 archive: DFMF), read by
    `neumat.io.ubo2014.read_ubo2014_table` (same texels, step, max_components, max_gib)."""
    table = read_ubo2014_table(path, texels=texels, step=step, max_components=max_components, device=device,
                               max_gib=max_gib)
    try:
        return TabulatedBTF.from_table(table, neighbours=neighbours)
    except InputError as e:
        raise DataFormatError(f"{Path(path)}: decoded table rejected: {e}") from None
