"""HEALPix (Gorski et al. 2005) in torch: ring-scheme pixel indexing, pixel corners, corner-vertex ids,
the NeuBRDF hemisphere grids S+ / S- and the hierarchy used for pruning.

Conventions follow healpy: theta is the colatitude from +z in [0, pi], phi the longitude in [0, 2 pi);
pixel indices are in the RING scheme unless a function says otherwise. Integer outputs are int64 on the
input's device. `nside` may be any positive integer for the ring-scheme functions (as in healpy); the
nested scheme and the hierarchy (`ring2nest`, `nest2ring`, `parent`, `ancestor_corner_vertices`) need
`nside` to be a power of two.

Details: src/neumat/methods/neubrdf/NOTES.md, section `neumat.nn.healpix`.
"""
from __future__ import annotations

import functools
import math

import torch

from neumat.core.checks import check_directions, check_finite, check_int
from neumat.core.errors import InputError
from neumat.core.tensors import cached_tensor
from neumat.nn import cpu_kernels

# face layout constants of the 12 base pixels (healpix_base.cc)
_JRLL = (2, 2, 2, 2, 3, 3, 3, 3, 4, 4, 4, 4)
_JPLL = (1, 3, 5, 7, 0, 2, 4, 6, 1, 3, 5, 7)


# ---------------------------------------------------------------------------------------------- checks

def check_nside(nside, name: str = "nside", power_of_two: bool = False) -> int:
    """Return `nside` as int; raise InputError unless it is a positive integer (and a power of 2 if asked)."""
    check_int(nside, name)
    if power_of_two and nside & (nside - 1):
        raise InputError(f"{name}: expected a power of two (nested scheme / hierarchy), got {nside}")
    return nside


def _check_pix(nside: int, pix: torch.Tensor, name: str = "pix") -> torch.Tensor:
    if not isinstance(pix, torch.Tensor) or pix.dtype.is_floating_point or pix.dtype == torch.bool:
        raise InputError(f"{name}: expected an integer tensor of pixel indices")
    if pix.numel() and (pix.min().item() < 0 or pix.max().item() >= 12 * nside * nside):
        raise InputError(f"{name}: pixel indices must lie in [0, {12 * nside * nside}) for nside {nside}")
    return pix.long()


def npix(nside: int) -> int:
    """Number of pixels, 12 nside^2."""
    return 12 * check_nside(nside) ** 2


def nvertices(nside: int) -> int:
    """Number of corner vertices on the sphere, 12 nside^2 + 2."""
    return 12 * check_nside(nside) ** 2 + 2


def hemisphere_size(nside: int) -> int:
    """Vertices n of one NeuBRDF hemisphere grid (equator and the ring past it included): 6 N^2 + 6 N + 1."""
    nside = check_nside(nside)
    return 6 * nside * nside + 6 * nside + 1


def grid_bytes(nside: int, grids: int, slot_bytes: int) -> int:
    """Bytes a model of `grids` pairs of NeuBRDF hemisphere grids takes at `nside`: `slot_bytes` per grid vertex,
    two int8 pruning levels per ring pixel, and the float32 vertex directions (for memory checks before
    allocating)."""
    return grids * (2 * hemisphere_size(nside) * slot_bytes + 2 * 12 * nside * nside) + 12 * nvertices(nside)


# --------------------------------------------------------------------------------- angles and pixels

def _isqrt(x: torch.Tensor) -> torch.Tensor:
    """floor(sqrt(x)) of a non-negative int64 tensor, exact."""
    r = torch.sqrt(x.double()).long()
    r = torch.where(r * r > x, r - 1, r)
    return torch.where((r + 1) * (r + 1) <= x, r + 1, r)


def _loc2pix(n: int, z: torch.Tensor, sth: torch.Tensor, tt: torch.Tensor) -> torch.Tensor:
    """Ring pixel (int32, or int64 past 2^31 pixels) of points with cos(theta) = z, sin(theta) = sth and
    tt = phi / (pi / 2) in [0, 4), all contiguous (healpy loc2pix; the polar caps use the sin(theta) form,
    accurate near the poles). A hot path, written with few, mostly in-place tensor operations and their
    constants as cached 0-dim tensors (a Python number is wrapped into a tensor on every operation). The
    floating-point steps are healpy's; the integer ones are healpy's simplified:
    - belt: healpy's ring ir = n + 1 + jp - jm and shift kshift = 1 - (ir & 1) make jp + jm - n + 1 + kshift
      odd, so its half is (jp + jm + 1 - n) >> 1 without kshift, and ncap + 4 n (ir - 1) = ncap + 4 n^2 +
      4 n (jp - jm);
    - caps: 2 ir (ir - 1) + ip (north) and npix - 2 ir (ir + 1) + ip (south) share ip - 2 ir."""
    c = _loc2pix_constants(n, z.dtype, z.device)
    za = z.abs()
    # equatorial belt: jp, jm index the pixel along the two families of boundary lines
    temp1 = tt.mul(c["n"]).add_(c["n/2"])
    temp2 = z.mul(c["3n/4"])
    jp = torch.sub(temp1, temp2).to(c["itype"])
    jm = temp1.add_(temp2).to(c["itype"])
    pix_eq = torch.add(jp, jm).add_(c["1-n"]).bitwise_right_shift_(c["1"]).remainder_(c["4n"])
    pix_eq.add_(jp.sub_(jm), alpha=4 * n).add_(c["ncap+4n^2"])
    # polar caps
    tp = torch.frac(tt)
    tmp = sth.mul(c["n"]).div_(za.add(c["1.0"]).mul_(c["1/3"]).sqrt_())
    jp = torch.mul(tp, tmp).to(c["itype"])
    jm = torch.sub(c["1.0"], tp).mul_(tmp).to(c["itype"])
    ir = jp.add_(jm).add_(c["1"])
    ip = torch.minimum(tt.mul(ir).to(c["itype"]), torch.add(c["-1"], ir, alpha=4))
    ir_squared = ir * ir
    ip.sub_(ir, alpha=2)
    pix_cap = torch.where(z > c["0.0"], ip.add(ir_squared, alpha=2), ip.sub_(ir_squared, alpha=2).add_(c["npix"]))
    return torch.where(za <= c["2/3"], pix_eq, pix_cap)


@functools.lru_cache(maxsize=64)
def _loc2pix_constants(n: int, dtype: torch.dtype, device: torch.device) -> dict:
    """The constants of `_loc2pix` and `vec2pix_xyz` for N_side n as 0-dim tensors: floats in `dtype` (the
    values Python numbers would round to in that dtype), integers in the pixel index type."""
    itype = torch.int32 if 12 * n * n < 2 ** 31 else torch.int64
    floats = {"n": n, "n/2": 0.5 * n, "3n/4": 0.75 * n, "1.0": 1.0, "1/3": 1 / 3, "0.0": 0.0, "2/3": 2 / 3,
              "2/pi": 2 / math.pi, "4.0": 4.0}
    ints = {"1": 1, "-1": -1, "1-n": 1 - n, "4n": 4 * n, "ncap+4n^2": 2 * n * (n - 1) + 4 * n * n,
            "npix": 12 * n * n}
    out = {k: cached_tensor(float(v), dtype, device) for k, v in floats.items()}
    out.update({k: cached_tensor(v, itype, device) for k, v in ints.items()})
    out["itype"] = itype
    return out


def _phi2tt(phi: torch.Tensor) -> torch.Tensor:
    """phi / (pi / 2) wrapped to [0, 4)."""
    tt = torch.remainder(phi * (2 / math.pi), 4.0)
    return tt.masked_fill_(tt >= 4.0, 0.0)


def ang2pix(nside: int, theta: torch.Tensor, phi: torch.Tensor) -> torch.Tensor:
    """Ring pixel (int64, same shape) of colatitude theta in [0, pi] and longitude phi (radians)."""
    nside = check_nside(nside)
    check_finite(theta, "theta")
    check_finite(phi, "phi")
    if theta.shape != phi.shape:
        raise InputError(f"theta, phi: expected equal shapes, got {tuple(theta.shape)} and {tuple(phi.shape)}")
    if theta.numel() and (theta.min().item() < 0 or theta.max().item() > math.pi + 1e-6):
        raise InputError("theta: colatitudes must lie in [0, pi]")
    return _loc2pix(nside, torch.cos(theta), torch.sin(theta).abs(), _phi2tt(phi)).long()


def vec2pix(nside: int, v: torch.Tensor) -> torch.Tensor:
    """Ring pixel (N,) int64 of unit vectors v (N, 3); raises InputError on non-unit input."""
    nside = check_nside(nside)
    check_directions(v, "v")
    return vec2pix_unchecked(nside, v)


def vec2pix_unchecked(nside: int, v: torch.Tensor) -> torch.Tensor:
    """`vec2pix` without input checks (hot path); v (N, 3) unit vectors, nside a positive int."""
    return vec2pix_xyz(nside, *(c.contiguous() for c in v.unbind(-1))).long()


def vec2pix_xyz(nside: int, x: torch.Tensor, y: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
    """Ring pixel (N,) int32 (int64 past 2^31 pixels) of unit vectors given as contiguous coordinate
    arrays x, y, z (N,); unchecked, the fastest form (strided coordinates slow atan2 down ~7x)."""
    c = _loc2pix_constants(nside, x.dtype, x.device)
    tt = torch.atan2(y, x).mul_(c["2/pi"]).remainder_(c["4.0"])  # tt + 4 where tt < 0
    tt.masked_fill_(tt >= c["4.0"], 0.0)  # a Python number: a tensor value would cost a host sync
    return _loc2pix(nside, z, torch.sqrt(x * x + y * y), tt)


def pix2ang(nside: int, pix: torch.Tensor, dtype: torch.dtype = torch.float64) -> tuple[torch.Tensor, torch.Tensor]:
    """(theta, phi) of ring pixel centres; computed in float64, returned in `dtype`."""
    nside = check_nside(nside)
    pix = _check_pix(nside, pix)
    z, sth, phi = _pix2zphi(nside, pix)
    return torch.atan2(sth, z).to(dtype), phi.to(dtype)


def pix2vec(nside: int, pix: torch.Tensor, dtype: torch.dtype = torch.float64) -> torch.Tensor:
    """Unit vectors (N, 3) of ring pixel centres."""
    nside = check_nside(nside)
    pix = _check_pix(nside, pix)
    z, sth, phi = _pix2zphi(nside, pix)
    return torch.stack([sth * torch.cos(phi), sth * torch.sin(phi), z], -1).to(dtype)


def _pix2zphi(n: int, pix: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    ncap, npix_ = 2 * n * (n - 1), 12 * n * n
    # north cap
    ir_n = (1 + _isqrt(1 + 2 * pix)) >> 1
    iphi_n = pix + 1 - 2 * ir_n * (ir_n - 1)
    # south cap
    ip_s = (npix_ - pix).clamp(min=1)
    ir_s = (1 + _isqrt(2 * ip_s - 1)) >> 1
    iphi_s = 4 * ir_s + 1 - (ip_s - 2 * ir_s * (ir_s - 1))
    # belt
    ip_e = pix - ncap
    tmp = torch.div(ip_e, 4 * n, rounding_mode="floor")
    ir_e = tmp + n
    iphi_e = ip_e - 4 * n * tmp + 1
    fodd = torch.where(((ir_e + n) & 1) == 1, 1.0, 0.5).double()

    north, south = pix < ncap, pix >= npix_ - ncap
    ir_cap = torch.where(north, ir_n, ir_s).double()
    t = ir_cap * ir_cap / (3.0 * n * n)  # 1 - |z| in the caps
    z_cap = torch.where(north, 1 - t, t - 1)
    sth_cap = torch.sqrt(t * (2 - t))
    phi_cap = (torch.where(north, iphi_n, iphi_s).double() - 0.5) * (math.pi / 2) / ir_cap
    z_eq = (2 * n - ir_e).double() * (2.0 / (3 * n))
    sth_eq = torch.sqrt((1 - z_eq) * (1 + z_eq))
    phi_eq = (iphi_e.double() - fodd) * (math.pi / (2 * n))
    cap = north | south
    return (torch.where(cap, z_cap, z_eq), torch.where(cap, sth_cap, sth_eq), torch.where(cap, phi_cap, phi_eq))


# ------------------------------------------------------------------------ face coordinates, nested scheme

def pix2xyf(nside: int, pix: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(ix, iy, face) of ring pixels, as healpy.pix2xyf(nside, pix, nest=False)."""
    nside = check_nside(nside)
    return _ring2xyf(nside, _check_pix(nside, pix))


def _ring2xyf(n: int, pix: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    ncap, npix_, nl2 = 2 * n * (n - 1), 12 * n * n, 2 * n
    jrll = torch.tensor(_JRLL, device=pix.device)
    jpll = torch.tensor(_JPLL, device=pix.device)
    # north cap
    ir_n = (1 + _isqrt(1 + 2 * pix)) >> 1
    iphi_n = pix + 1 - 2 * ir_n * (ir_n - 1)
    face_n = torch.div(iphi_n - 1, ir_n.clamp(min=1), rounding_mode="floor")
    # belt
    ip = pix - ncap
    tmp = torch.div(ip, 4 * n, rounding_mode="floor")
    ir_e = tmp + n
    iphi_e = ip - tmp * 4 * n + 1
    ire, irm = tmp + 1, nl2 + 1 - tmp
    ifm = torch.div(iphi_e - (ire >> 1) + n - 1, n, rounding_mode="floor")
    ifp = torch.div(iphi_e - (irm >> 1) + n - 1, n, rounding_mode="floor")
    face_e = torch.where(ifp == ifm, ifp | 4, torch.where(ifp < ifm, ifp, ifm + 8))
    # south cap
    ips = (npix_ - pix).clamp(min=1)
    ir_s = (1 + _isqrt(2 * ips - 1)) >> 1
    iphi_s = 4 * ir_s + 1 - (ips - 2 * ir_s * (ir_s - 1))
    face_s = torch.div(iphi_s - 1, ir_s.clamp(min=1), rounding_mode="floor") + 8

    north, south = pix < ncap, pix >= npix_ - ncap
    iring = torch.where(north, ir_n, torch.where(south, 2 * nl2 - ir_s, ir_e))
    iphi = torch.where(north, iphi_n, torch.where(south, iphi_s, iphi_e))
    nr = torch.where(north, ir_n, torch.where(south, ir_s, torch.full_like(pix, n)))
    kshift = torch.where(north | south, torch.zeros_like(pix), (ir_e + n) & 1)
    face = torch.where(north, face_n, torch.where(south, face_s, face_e))
    irt = iring - jrll[face] * n + 1
    ipt = 2 * iphi - jpll[face] * nr - kshift - 1
    ipt = torch.where(ipt >= 2 * nl2, ipt - 8 * n, ipt)
    return (ipt - irt) >> 1, (-ipt - irt) >> 1, face


def _xyf2ring(n: int, ix: torch.Tensor, iy: torch.Tensor, face: torch.Tensor) -> torch.Tensor:
    jrll = torch.tensor(_JRLL, device=ix.device)
    jpll = torch.tensor(_JPLL, device=ix.device)
    jr = jrll[face] * n - ix - iy - 1  # pixel-centre ring, 1 .. 4n - 1
    north, south = jr < n, jr >= 3 * n
    ncap = 2 * n * (n - 1)
    s = 4 * n - jr
    n_before = torch.where(north, 2 * jr * (jr - 1),
                           torch.where(south, 12 * n * n - 2 * s * (s + 1), ncap + (jr - n) * 4 * n))
    nr = torch.where(north, jr, torch.where(south, s, torch.full_like(jr, n)))
    shifted = north | south | (((jr - n) & 1) == 0)
    kshift = 1 - shifted.long()
    jp = torch.div(jpll[face] * nr + ix - iy + 1 + kshift, 2, rounding_mode="floor")
    jp = torch.where(jp < 1, jp + 4 * n, jp)
    return n_before + jp - 1


def _spread_bits(v: torch.Tensor) -> torch.Tensor:
    out = torch.zeros_like(v)
    for b in range(31):
        out |= ((v >> b) & 1) << (2 * b)
    return out


def _compress_bits(v: torch.Tensor) -> torch.Tensor:
    out = torch.zeros_like(v)
    for b in range(31):
        out |= ((v >> (2 * b)) & 1) << b
    return out


def ring2nest(nside: int, pix: torch.Tensor) -> torch.Tensor:
    """Nested index of ring pixels (nside a power of two)."""
    nside = check_nside(nside, power_of_two=True)
    ix, iy, face = _ring2xyf(nside, _check_pix(nside, pix))
    return face * nside * nside + _spread_bits(ix) + (_spread_bits(iy) << 1)


def nest2ring(nside: int, pix: torch.Tensor) -> torch.Tensor:
    """Ring index of nested pixels (nside a power of two)."""
    nside = check_nside(nside, power_of_two=True)
    pix = _check_pix(nside, pix)
    face = torch.div(pix, nside * nside, rounding_mode="floor")
    local = pix - face * nside * nside
    return _xyf2ring(nside, _compress_bits(local), _compress_bits(local >> 1), face)


def parent(nside: int, pix: torch.Tensor) -> torch.Tensor:
    """Ring pixel at nside // 2 that contains ring pixel `pix` at `nside` (nested parent = nest >> 2)."""
    nside = check_nside(nside, power_of_two=True)
    if nside == 1:
        raise InputError("nside: the 12 base pixels (nside 1) have no parent")
    return nest2ring(nside // 2, ring2nest(nside, pix) >> 2)


# ------------------------------------------------------------------------------------------- vertices

def _ring_start(n: int, r: torch.Tensor) -> torch.Tensor:
    """Id of the first vertex on vertex ring r (0 .. 4n)."""
    s = 4 * n - r
    start = torch.where(r <= n, 1 + 2 * r * (r - 1), torch.where(
        r >= 3 * n, 12 * n * n + 1 - 2 * s * (s + 1), 1 + 2 * n * (n - 1) + 4 * n * (r - n)))
    return torch.where(r == 0, torch.zeros_like(start), start)


def _xyf2vertex(n: int, x: torch.Tensor, y: torch.Tensor, face: torch.Tensor) -> torch.Tensor:
    """Vertex id of the integer face-coordinate point (x, y) in [0, n]^2 of `face`."""
    jrll = torch.tensor(_JRLL, device=x.device)[face]
    jpll = torch.tensor(_JPLL, device=x.device)[face]
    r = jrll * n - x - y  # vertex ring
    nr = torch.where(r < n, r, torch.where(r > 3 * n, 4 * n - r, torch.full_like(r, n)))
    t = jpll * nr + x - y  # twice the azimuth in units of pi / (2 nr)
    count = (4 * nr).clamp(min=1)
    j = torch.remainder(torch.div(torch.remainder(t, 2 * count), 2, rounding_mode="floor"), count)
    return _ring_start(n, r) + torch.where(nr == 0, torch.zeros_like(j), j)


def corner_vertices(nside: int, pix: torch.Tensor) -> torch.Tensor:
    """Vertex ids (N, 4) of the corners of ring pixels, ordered north, west, south, east (healpy.boundaries)."""
    nside = check_nside(nside)
    return _corner_vertices(nside, _check_pix(nside, pix), 0)


def _corner_vertices(n: int, pix: torch.Tensor, level) -> torch.Tensor:
    """Corner vertex ids (N, 4) of the level-`level` ancestor of ring pixels (level 0: the pixel itself); on the CPU
    by the fused kernel (`cpu_kernels.healpix_corner_vertices`, the same ids)."""
    if pix.device.type == "cpu" and (not isinstance(level, torch.Tensor) or level.device.type == "cpu") \
            and cpu_kernels.usable():
        return cpu_kernels.healpix_corner_vertices(n, pix, level)
    ix, iy, face = _ring2xyf(n, pix)
    level = torch.as_tensor(level, device=pix.device)
    x0, y0, s = (ix >> level) << level, (iy >> level) << level, 1 << level
    xs = torch.stack([x0 + s, x0, x0, x0 + s], -1)
    ys = torch.stack([y0 + s, y0 + s, y0, y0], -1)
    return _xyf2vertex(n, xs, ys, face.unsqueeze(-1).expand_as(xs))


def ancestor_corner_vertices(nside: int, pix: torch.Tensor, level: torch.Tensor | int) -> torch.Tensor:
    """Corner vertex ids (N, 4), in the nside vertex numbering, of the ancestor `level` steps up of each
    ring pixel (level 0: the pixel; 1: `parent`). Coarse vertices are a subset of the fine ones."""
    nside = check_nside(nside, power_of_two=True)
    pix = _check_pix(nside, pix)
    lv = torch.as_tensor(level, device=pix.device).long()
    if lv.numel() and (lv.min().item() < 0 or (1 << lv.max().item()) > nside):
        raise InputError(f"level: expected 0 <= level <= log2(nside) = {nside.bit_length() - 1}")
    return _corner_vertices(nside, pix, lv)


def vertex2vec(nside: int, vid: torch.Tensor, dtype: torch.dtype = torch.float64) -> torch.Tensor:
    """Unit vectors (..., 3) of vertex ids (any shape); computed in float64, returned in `dtype`."""
    n = check_nside(nside)
    if not isinstance(vid, torch.Tensor) or vid.dtype.is_floating_point:
        raise InputError("vid: expected an integer tensor of vertex ids")
    vid = vid.long()
    if vid.numel() and (vid.min().item() < 0 or vid.max().item() >= 12 * n * n + 2):
        raise InputError(f"vid: vertex ids must lie in [0, {12 * n * n + 2}) for nside {n}")
    nv = 12 * n * n + 2
    # north cap rings 1..n: start 1 + 2r(r-1); south cap mirrored; belt linear
    r_n = (1 + _isqrt(2 * (vid - 1).clamp(min=0) + 1)) >> 1  # largest r with 1 + 2r(r-1) <= vid
    vs = (nv - 1 - vid).clamp(min=0)  # id counted from the south pole
    s_s = (1 + _isqrt(2 * (vs - 1).clamp(min=0) + 1)) >> 1
    r_e = n + torch.div(vid - (1 + 2 * n * (n - 1)), 4 * n, rounding_mode="floor")
    r = torch.where(vid == 0, torch.zeros_like(vid), torch.where(
        r_n < n, r_n, torch.where(vid == nv - 1, torch.full_like(vid, 4 * n),
                                  torch.where(s_s < n, 4 * n - s_s, r_e))))
    j = vid - _ring_start(n, r)
    nr = torch.where(r < n, r, torch.where(r > 3 * n, 4 * n - r, torch.full_like(r, n))).double()
    t = nr * nr / (3.0 * n * n)
    cap = (r < n) | (r > 3 * n)
    z = torch.where(cap, torch.where(r < n, 1 - t, t - 1), (2 * n - r).double() * (2.0 / (3 * n)))
    sth = torch.where(cap, torch.sqrt(t * (2 - t)), torch.sqrt((1 - z) * (1 + z)))
    shift = torch.where(cap, 0.0, ((r - n) & 1).double() * 0.5)
    phi = (j.double() + shift) * (math.pi / 2) / nr.clamp(min=1)
    return torch.stack([sth * torch.cos(phi), sth * torch.sin(phi), z], -1).to(dtype)


def corners(nside: int, pix: torch.Tensor, dtype: torch.dtype = torch.float64) -> torch.Tensor:
    """Corner unit vectors (N, 4, 3) of ring pixels, in healpy.boundaries(nside, pix, step=1) order (N, W, S, E)."""
    return vertex2vec(nside, corner_vertices(nside, pix), dtype)


# ------------------------------------------------------------------------------ interpolation weights

def great_circle_distance(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Angle (...,) in radians between unit vectors a, b (..., 3); accurate for small and large angles."""
    return torch.atan2(torch.linalg.vector_norm(torch.cross(a, b, dim=-1), dim=-1), (a * b).sum(-1))


def idw_weights(w: torch.Tensor, corner_dirs: torch.Tensor, eps: float = 1e-7) -> torch.Tensor:
    """Normalised inverse great-circle-distance weights (N, 4) of directions w (N, 3) with respect to
    corner directions (N, 4, 3) (NeuBRDF training weights). A direction on a vertex gets weight ~1 there."""
    d = great_circle_distance(w.unsqueeze(1), corner_dirs).clamp(min=eps)
    inv = 1.0 / d
    return inv / inv.sum(-1, keepdim=True)


# ------------------------------------------------------------------------------------ NeuBRDF grids

def south_grid_offset(nside: int) -> int:
    """Offset from sphere vertex id to S- slot: a vertex v on rings 2N-1 .. 4N (the last n vertex ids,
    starting at V - n) sits at sphere-grid slot v + 2 n - V."""
    n = check_nside(nside)
    return 2 * hemisphere_size(n) - nvertices(n)


def hemisphere_direction(w: torch.Tensor, south: bool) -> torch.Tensor:
    """Direction used for a grid lookup: w with z clamped to >= 0 (upper hemisphere), mirrored to
    (pi - theta, phi), i.e. z -> -z, for the south grid. Shape (N, 3)."""
    x, y, z = w.unbind(-1)
    z = z.clamp(min=0)
    return torch.stack([x, y, -z if south else z], -1)


def mirror_pixels(nside: int) -> torch.Tensor:
    """Ring pixel (12 nside^2,) int64 holding the mirror image (pi - theta, phi) of each ring pixel: the same
    position in ring 4 nside - r as in ring r (HEALPix is symmetric about the equator)."""
    nside = check_nside(nside)
    centres = pix2vec(nside, torch.arange(12 * nside * nside))
    return vec2pix_unchecked(nside, centres * torch.tensor([1.0, 1.0, -1.0], dtype=centres.dtype))


def grid_corners(nside: int, w: torch.Tensor, south: bool, levels: torch.Tensor | None = None
                 ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """NeuBRDF grid lookup of directions w (N, 3), unchecked (hot path).

    Returns (slots (N, 4) int64 into the merged 2 n sphere grid, vertex ids (N, 4), lookup direction
    (N, 3)): `hemisphere_direction(w, south)`, its ring pixel, and the corners of that pixel, or of its
    ancestor `levels[pix]` steps up when a per-pixel level table (12 nside^2,) from `pruned_levels` is given.
    """
    d = hemisphere_direction(w, south)
    pix = vec2pix_unchecked(nside, d)
    slots, vid = pixel_corner_slots(nside, pix, south, 0 if levels is None else levels[pix].long())
    return slots, vid, d


def pixel_corner_slots(nside: int, pix: torch.Tensor, south: bool, level: torch.Tensor | int = 0
                       ) -> tuple[torch.Tensor, torch.Tensor]:
    """(slots (N, 4) into the merged 2 n sphere grid, vertex ids (N, 4)) of the corners of the level-`level`
    ancestors of ring pixels pix (N,) on the S+ (south False) or S- grid; unchecked (hot path)."""
    vid = _corner_vertices(nside, pix, level)
    return (vid + south_grid_offset(nside) if south else vid), vid


def grid_vertex_ids(nside: int) -> torch.Tensor:
    """Sphere vertex id (2 n,) held by each slot of the merged sphere grid [S+, S-]; the rings
    2N-1, 2N, 2N+1 appear twice."""
    n = check_nside(nside)
    h = hemisphere_size(n)
    return torch.cat([torch.arange(h), torch.arange(h) + nvertices(n) - h])


def grid_slot_directions(nside: int) -> torch.Tensor:
    """Unit directions (2 n, 3) float64 that the slots of the merged sphere grid [S+, S-] stand for as upper-hemisphere
    lookups: an S+ slot its vertex direction, an S- slot the mirror image (z negated) of its vertex, i.e. the wo whose
    mirrored lookup lands on it; slots past the equator take the equator's direction. What re-sampling a grid at
    another N_side evaluates (`NeuBRDF.regrid`)."""
    n = check_nside(nside)
    h = hemisphere_size(n)
    dirs = vertex2vec(n, grid_vertex_ids(n), torch.float64)
    dirs[h:, 2] = -dirs[h:, 2]  # a south slot holds the mirror image of an upper-hemisphere wo
    dirs[:, 2] = dirs[:, 2].clamp(min=0)
    return torch.nn.functional.normalize(dirs, dim=-1)


def supervised_pixels(nside: int, dirs: torch.Tensor) -> torch.Tensor:
    """Mask (12 nside^2,) of ring pixels that contain at least one of the unit directions dirs (N, 3)."""
    nside = check_nside(nside)
    check_directions(dirs, "dirs")
    mask = torch.zeros(12 * nside * nside, dtype=torch.bool, device=dirs.device)
    mask[vec2pix_unchecked(nside, dirs)] = True
    return mask


def touched_vertices(nside: int, dirs: torch.Tensor) -> torch.Tensor:
    """Mask (12 nside^2 + 2,) of vertices that are corners of a pixel containing one of dirs (N, 3):
    the vertices that receive gradient when training on these directions; the others can be pruned."""
    nside = check_nside(nside)
    check_directions(dirs, "dirs")
    mask = torch.zeros(12 * nside * nside + 2, dtype=torch.bool, device=dirs.device)
    mask[_corner_vertices(nside, torch.unique(vec2pix_unchecked(nside, dirs)), 0).reshape(-1)] = True
    return mask


def pruned_levels(nside: int, supervised: torch.Tensor) -> torch.Tensor:
    """Hierarchy level (12 nside^2,) int64 of every ring pixel after pruning: 0 for a supervised pixel,
    else the number of `parent` steps to the first ancestor that contains a supervised pixel (capped at
    log2 nside). Use with `ancestor_corner_vertices` to build the multi-resolution sparse grid."""
    nside = check_nside(nside, power_of_two=True)
    if not isinstance(supervised, torch.Tensor) or supervised.dtype != torch.bool \
            or supervised.shape != (12 * nside * nside,):
        raise InputError(f"supervised: expected a bool mask of shape ({12 * nside * nside},)")
    nest_sup = torch.zeros_like(supervised)
    pix = torch.arange(12 * nside * nside, device=supervised.device)
    nest = ring2nest(nside, pix)
    nest_sup[nest] = supervised
    level = torch.zeros_like(pix)
    found = nest_sup.clone()
    for lv in range(1, nside.bit_length()):
        block = nest_sup.view(-1, 4 ** lv).any(-1)  # supervised anywhere in the level-lv ancestor
        has = block.repeat_interleave(4 ** lv)
        level = torch.where(~found & has, torch.full_like(level, lv), level)
        found |= has
    level = torch.where(found, level, torch.full_like(level, nside.bit_length() - 1))
    return level[nest]


def shared_ancestor_levels(nside: int, levels: torch.Tensor) -> torch.Tensor:
    """Bit mask (12 nside^2,) int64 per ring pixel p of a pruned grid (`levels` from `pruned_levels`): bit
    L >= 1 is set when p's level-L ancestor is read by some pixel of level L, i.e. when its corners hold
    the features of pruned pixels. Training lookups of directions in p at those levels train them."""
    nside = check_nside(nside, power_of_two=True)
    if not isinstance(levels, torch.Tensor) or levels.shape != (12 * nside * nside,):
        raise InputError(f"levels: expected a tensor of shape ({12 * nside * nside},)")
    pix = torch.arange(12 * nside * nside, device=levels.device)
    nest = ring2nest(nside, pix)
    lv = torch.empty_like(pix)
    lv[nest] = levels.long()
    mask = torch.zeros_like(pix)
    for l in range(1, nside.bit_length()):
        used = (lv == l).view(-1, 4 ** l).any(-1)
        mask |= used.long().repeat_interleave(4 ** l) << l
    return mask[nest]


def check_levels(levels: torch.Tensor, nside: int, name: str) -> torch.Tensor:
    """Check pruning levels (any shape, integer) against the hierarchy of `nside`: 0 .. log2 nside."""
    top = nside.bit_length() - 1
    if levels.is_floating_point() or (levels.numel() and (int(levels.min()) < 0 or int(levels.max()) > top)):
        got = f"dtype {levels.dtype}" if levels.is_floating_point() else f"[{int(levels.min())}, {int(levels.max())}]"
        raise InputError(f"{name}: expected integer pruning levels in [0, {top}] (log2 nside = {top}), got {got}")
    return levels


@functools.lru_cache(maxsize=16)
def grid_level_cap(nside: int, south: bool) -> torch.Tensor:
    """Largest hierarchy level (12 nside^2,) int64 at which each ring pixel's ancestor still has all 4
    corners on the S+ grid (vertex rings 0 .. 2 nside + 1; `south` False) or on S- (rings 2 nside - 1 ..
    4 nside); -1 for pixels with corners off the grid. Pruned lookups must not climb past it: coarse
    pixels near the equator span both hemispheres. Cached per (nside, south) on the CPU: do not modify."""
    nside = check_nside(nside, power_of_two=True)
    pix = torch.arange(12 * nside * nside)
    h, v = hemisphere_size(nside), nvertices(nside)
    cap = torch.full_like(pix, -1)
    for l in range(nside.bit_length()):
        vid = _corner_vertices(nside, pix, l)
        on_grid = ((vid >= v - h) if south else (vid < h)).all(-1)
        cap = torch.where(on_grid, torch.full_like(cap, l), cap)
    return cap
