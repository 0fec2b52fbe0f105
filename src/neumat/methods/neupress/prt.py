"""Spherical harmonic PRT from a NeuPreSS-style full-sphere material (TG et al., Sec. 4.3, Eqs. 9-11).

Per vertex and view bin, S_hat is projected onto real SH in wi (Eq. 10), an environment onto the same basis
(Eq. 9), and the radiance is their dot product (Eq. 11). View bins: view_theta x view_phi of equal solid angle;
light quadrature "gauss" (default, exact for band-limited transport) or "fibonacci".

Details: src/neumat/methods/neupress/NOTES.md, section `neumat.methods.neupress.prt`.
"""
from __future__ import annotations

import copy
import math
import operator
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import TYPE_CHECKING, Callable

import numpy as np
import torch

from neumat.core.checks import check_directions, check_finite, check_shape
from neumat.core.errors import DataFormatError, InputError
from neumat.core.frames import frame_from_normal, to_local, to_world
from neumat.core.query import Query
from neumat.io.tagged_file import read_tagged, write_tagged
from neumat.nn.codebook import float_bits, storage_bytes
from neumat.nn.spherical_harmonics import real_sh, sh_count

if TYPE_CHECKING:
    from neumat.render.lights import EnvironmentMap, Light

LIGHT_RULES = ("gauss", "fibonacci")
PRECISIONS = ("fp32", "bf16")
FILE_TYPE = "sh-prt"
#: view bins (theta, phi), light directions and arithmetic of `neumat translucent prt` (the paper's 16 x 64 x 1024
#: in float32 are the PRTConfig defaults): 8 x 16 x 32 is 253x fewer evaluations per vertex, bfloat16 about 3x
#: faster each, for meshes of tens of thousands of vertices in minutes; what this costs against the paper's
#: counts and float32 is measured in benchmarks/studies/neupress/results/neupress_prt.md
FAST_VIEW_BINS = (8, 16)
FAST_LIGHT_SAMPLES = 32
FAST_PRECISION = "bf16"


@dataclass
class PRTConfig:
    """SH PRT precomputation settings; defaults are the paper's (Sec. 4.3 and 5)."""

    degree: int = 2
    """SH degree L in wi (the paper: l <= 2, nine coefficients); (L + 1)^2 coefficients per view bin."""
    view_theta: int = 16
    """View bins in cos theta on the hemisphere around each vertex normal (the paper: 16)."""
    view_phi: int = 64
    """View bins in phi (the paper: 64)."""
    light_samples: int = 1024
    """Quadrature directions wi over the sphere for Eq. 10 (about this many for the "gauss" rule)."""
    light_rule: str = "gauss"
    """Quadrature rule for wi: "gauss" (Gauss-Legendre x uniform phi) or "fibonacci" (see the module doc)."""
    precision: str = "fp32"
    """Arithmetic of the material's evaluations: "fp32", or "bf16" for NeuPreSS models (Fourier angles in float32,
    their cosines and the MLP in bfloat16, projection in float32: 2-3x faster on CPUs with AVX-512 BF16, a_lm
    within ~1% of float32; benchmarks/studies/neupress/results/neupress_prt.md)."""
    batch_size: int = 65536
    """Material evaluations per batch."""


def _positive_int(value, name: str, minimum: int = 1) -> int:
    try:
        v = operator.index(value)
    except TypeError:
        v = None
    if v is None or isinstance(value, bool) or v < minimum:
        raise InputError(f"{name}: expected an integer >= {minimum}, got {value!r}")
    return v


def check_config(c: PRTConfig) -> PRTConfig:
    """`c`, or InputError naming its first bad field; callers check before slow work (loading Mitsuba)."""
    if not isinstance(c, PRTConfig):
        raise InputError(f"config: expected a PRTConfig, got {type(c).__name__}")
    _positive_int(c.degree, "PRTConfig.degree", 0)
    for name in ("view_theta", "view_phi", "light_samples", "batch_size"):
        _positive_int(getattr(c, name), f"PRTConfig.{name}")
    if c.light_rule not in LIGHT_RULES:
        raise InputError(f"PRTConfig.light_rule: expected one of {LIGHT_RULES}, got {c.light_rule!r}")
    if c.precision not in PRECISIONS:
        raise InputError(f"PRTConfig.precision: expected one of {PRECISIONS}, got {c.precision!r}")
    return c


# ---- quadrature -----------------------------------------------------------------------------------------------
def sphere_quadrature(samples: int, rule: str = "gauss", dtype=torch.float64, device=None
                      ) -> tuple[torch.Tensor, torch.Tensor]:
    """Deterministic quadrature over the unit sphere: directions (M, 3) and weights (M,) in steradians (they
    sum to 4 pi). rule "gauss": Gauss-Legendre in z times uniform phi (M close to `samples`); "fibonacci":
    exactly `samples` Fibonacci-sphere points with equal weights. See the module docstring."""
    samples = _positive_int(samples, "samples")
    if rule not in LIGHT_RULES:
        raise InputError(f"rule: expected one of {LIGHT_RULES}, got {rule!r}")
    if rule == "gauss":
        n_z = max(1, round(math.sqrt(samples / 2)))
        n_phi = max(1, samples // n_z)
        z, wz = np.polynomial.legendre.leggauss(n_z)
        phi = (np.arange(n_phi) + 0.5) * (2 * math.pi / n_phi)
        zz, pp = np.meshgrid(z, phi, indexing="ij")
        weights = np.repeat(wz * (2 * math.pi / n_phi), n_phi)
    else:
        j = np.arange(samples)
        zz = 1 - (2 * j + 1) / samples
        pp = np.remainder(j * math.pi * (3 - math.sqrt(5)), 2 * math.pi)  # golden angle
        weights = np.full(samples, 4 * math.pi / samples)
    zz, pp = zz.ravel(), pp.ravel()
    s = np.sqrt(np.clip(1 - zz * zz, 0, None))
    d = np.stack([s * np.cos(pp), s * np.sin(pp), zz], -1)
    return (torch.as_tensor(d, dtype=dtype, device=device), torch.as_tensor(weights, dtype=dtype, device=device))


def view_bin_directions(view_theta: int, view_phi: int, dtype=torch.float32, device=None) -> torch.Tensor:
    """Local-frame (z = normal) centre directions (view_theta, view_phi, 3) of the equal-solid-angle view bins."""
    view_theta = _positive_int(view_theta, "view_theta")
    view_phi = _positive_int(view_phi, "view_phi")
    cos_t = 1 - (torch.arange(view_theta, dtype=torch.float64) + 0.5) / view_theta
    phi = (torch.arange(view_phi, dtype=torch.float64) + 0.5) * (2 * math.pi / view_phi)
    sin_t = (1 - cos_t * cos_t).clamp(min=0).sqrt()
    d = torch.stack([sin_t[:, None] * torch.cos(phi)[None], sin_t[:, None] * torch.sin(phi)[None],
                     cos_t[:, None].expand(view_theta, view_phi)], -1)
    return d.to(dtype=dtype, device=device)


# ---- lighting coefficients (Eq. 9) -------------------------------------------------------------------------------
def sh_light_coefficients(env, degree: int, samples: int = 4096, rule: str = "gauss",
                          texel_nodes: int | None = None) -> torch.Tensor:
    """b_lm = integral L_env(w) Y_lm(w) dw (Eq. 9), (C, 3) float32 with C = (degree + 1)^2.

    env: an `EnvironmentMap`: integrated texel by texel, each texel's (constant) radiance times the integral of
      Y_lm over the texel, by a texel_nodes x texel_nodes Gauss-Legendre rule in (theta, phi) with the sin theta
      Jacobian (None: the smallest order whose error bound for degree-`degree` SH is below 1e-8 relative:
      1-2 for ordinary maps, more for tiny ones); texel_nodes = 1 is the texel-centre direction weighted by the
      texel's exact solid angle (error O(texel size^2));
    a `DirectionalLight`: b = E Y_lm(d) (irradiance E arriving from d);
    any other distant `Light` (its `eval`) or a callable radiance(d (N, 3) float64) -> (N, 3): integrated with
      `sphere_quadrature(samples, rule)`.
    Directions are in the light's (world = object) space.
    """
    from neumat.render.lights import DirectionalLight, EnvironmentMap, Light, PointLight

    sh_count(degree)  # validates degree
    degree = operator.index(degree)
    if isinstance(env, EnvironmentMap):
        k = _texel_nodes(env, degree) if texel_nodes is None else _positive_int(texel_nodes, "texel_nodes")
        return _envmap_coefficients(env, degree, k).float()
    if isinstance(env, DirectionalLight):
        d = env.direction.double().cpu()[None]
        return (real_sh(d, degree)[0, :, None] * env.irradiance.double().cpu().expand(3)[None]).float()
    if isinstance(env, PointLight):
        raise InputError("env: a point light is not distant; SH PRT needs distant lighting")
    if not (isinstance(env, Light) or callable(env)):
        raise InputError(f"env: expected an EnvironmentMap, a distant Light or a callable radiance(d), "
                         f"got {type(env).__name__}")
    fn = env.eval if isinstance(env, Light) else env
    d, w = sphere_quadrature(samples, rule)
    radiance = fn(d)
    if not isinstance(radiance, torch.Tensor):
        raise InputError(f"env: the radiance callable returned {type(radiance).__name__}, expected a tensor")
    check_shape(radiance, "env radiance", (d.shape[0], 3))
    radiance = radiance.double().cpu()
    check_finite(radiance, "env radiance")
    return (real_sh(d, degree).T @ (radiance * w[:, None])).float()


def _texel_nodes(env, degree: int, tol: float = 1e-8) -> int:
    """Smallest Gauss-Legendre order n whose error bound (omega h)^2n (n!)^4 / ((2n + 1) ((2n)!)^3) for a
    band-limit omega = degree + 1 over a texel of side h (radians) is below tol."""
    h = max(math.pi / env.height, 2 * math.pi / env.width)
    x = (degree + 1) * h
    for n in range(1, 17):
        if x ** (2 * n) * math.factorial(n) ** 4 / ((2 * n + 1) * math.factorial(2 * n) ** 3) < tol:
            return n
    return 16


def _envmap_coefficients(env, degree: int, k: int, max_points: int = 1 << 20) -> torch.Tensor:
    """(C, 3) float64 integral of an EnvironmentMap against Y_lm, texel by texel (see `sh_light_coefficients`)."""
    h, wd = env.height, env.width
    theta_edges = torch.arange(h + 1, dtype=torch.float64) * (math.pi / h)
    if k == 1:  # texel centres with exact solid angles
        nodes, node_w = torch.tensor([0.5], dtype=torch.float64), torch.ones(1, dtype=torch.float64)
        cos_e = torch.cos(theta_edges)
        row_w = cos_e[:-1] - cos_e[1:]  # (H,) integral of sin theta over each row
    else:
        x, wx = np.polynomial.legendre.leggauss(k)
        nodes, node_w = torch.as_tensor((x + 1) / 2), torch.as_tensor(wx / 2)  # on [0, 1], weights sum to 1
        row_w = None
    theta = theta_edges[:-1, None] + nodes[None] * (math.pi / h)  # (H, k)
    phi = (torch.arange(wd, dtype=torch.float64)[:, None] + nodes[None]) * (2 * math.pi / wd) - env.rotation_rad
    sin_p, cos_p = torch.sin(phi).reshape(-1), torch.cos(phi).reshape(-1)  # (W k,)
    phi_w = node_w.repeat(wd) * (2 * math.pi / wd)  # (W k,)
    image = env.image.double().cpu()
    out = torch.zeros(sh_count(degree), 3, dtype=torch.float64)
    rows = max(1, max_points // (wd * k * k))
    for r0 in range(0, h, rows):
        r1 = min(r0 + rows, h)
        th = theta[r0:r1].reshape(-1)  # (R k,)
        if row_w is None:
            th_w = (node_w[None] * torch.sin(theta[r0:r1]) * (math.pi / h)).reshape(-1)
        else:
            th_w = row_w[r0:r1].repeat_interleave(k)
        st, ct = torch.sin(th)[:, None], torch.cos(th)[:, None]
        d = torch.stack([st * sin_p[None], ct.expand(-1, len(sin_p)), -st * cos_p[None]], -1).reshape(-1, 3)
        w = (th_w[:, None] * phi_w[None]).reshape(-1)
        # radiance of each node: its texel's, rows (R, k) x columns (W, k)
        rad = image[r0:r1, None, :, None, :].expand(-1, k, -1, k, -1).reshape(-1, 3)
        out += real_sh(d, degree).T @ (rad * w[:, None])
    return out


# ---- the PRT table ---------------------------------------------------------------------------------------------
class SHPRT:
    """Per-vertex, per-view-bin SH transport coefficients a_lm (Eq. 10) and their use (Eq. 11).

    coefficients: (V, view_theta, view_phi, C, 3) float32, C = (degree + 1)^2; points, normals: (V, 3) object-
    space vertex positions and unit normals (the normals define the view bins); faces: optional (F, 3) long
    vertex indices of the mesh's triangles (for rendering). Build with `from_material`.
    """

    def __init__(self, coefficients: torch.Tensor, points: torch.Tensor, normals: torch.Tensor,
                 config: PRTConfig | None = None, faces: torch.Tensor | None = None) -> None:
        cfg = check_config(PRTConfig() if config is None else config)
        _check_vertices(points, normals)
        v = points.shape[0]
        check_shape(coefficients, "coefficients", (v, cfg.view_theta, cfg.view_phi, sh_count(cfg.degree), 3))
        if not coefficients.is_floating_point():
            raise InputError(f"coefficients: expected a floating-point tensor, got {coefficients.dtype}")
        check_finite(coefficients, "coefficients")
        self.config = cfg
        self.coefficients = coefficients.float()
        device = self.coefficients.device
        self.points = points.float().to(device)
        self.normals = normals.float().to(device)
        self.faces = None if faces is None else _check_faces(faces, v).to(device)

    # ---- properties ------------------------------------------------------------------------------------------
    @property
    def degree(self) -> int:
        return self.config.degree

    @property
    def num_coefficients(self) -> int:
        return sh_count(self.config.degree)

    @property
    def num_vertices(self) -> int:
        return self.coefficients.shape[0]

    @property
    def device(self) -> torch.device:
        return self.coefficients.device

    def to(self, device) -> "SHPRT":
        """The same table on `device`."""
        return SHPRT(self.coefficients.to(device), self.points.to(device), self.normals.to(device), self.config,
                     self.faces)

    def size_bytes(self, precision: str = "fp16") -> int:
        """Storage of the coefficients at `precision` ("fp16" or "fp32"). Vertex positions and normals are
        not counted: the mesh holds them."""
        return storage_bytes(self.coefficients.numel() * float_bits(precision))

    # ---- precomputation (Eq. 10) -----------------------------------------------------------------------------
    @classmethod
    def from_material(cls, material, points: torch.Tensor, normals: torch.Tensor, config: PRTConfig | None = None,
                      progress: bool = False, device=None, faces: torch.Tensor | None = None) -> "SHPRT":
        """Project `material`'s S_hat onto SH in wi at every vertex and view-bin centre.

        material: a full-sphere material (`full_sphere = True`, e.g. NeuPreSS) whose `eval(Query(wi, wo, x, n))`
        gives S_hat (N, 3); points, normals (V, 3): object-space vertices and unit normals; faces: optional
        (F, 3) triangles, kept with the table. Evaluation is in `config.precision` on `device` (default: the
        device of `points`), in chunks of about `config.batch_size` evaluations (whole light sets of (vertex, view)
        pairs), each chunk projected by one float32 matrix product. A NeuPreSS model is evaluated through
        `_SeparableNeuPreSS` (no per-query Fourier features); other materials through `eval(Query)`.
        """
        cfg = check_config(PRTConfig() if config is None else config)
        if not callable(getattr(material, "eval", None)):
            raise InputError(f"material: expected a Material with eval(Query), got {type(material).__name__}")
        if not getattr(material, "full_sphere", False):
            raise InputError(f"material: expected a full-sphere material (translucent object, full_sphere = True), "
                             f"got {type(material).__name__}")
        _check_vertices(points, normals)
        device = points.device if device is None else torch.device(device)
        pts, nrm = points.to(device, torch.float32), normals.to(device, torch.float32)
        nrm = nrm / nrm.norm(dim=-1, keepdim=True)
        t, b = frame_from_normal(nrm)

        wi, weights = sphere_quadrature(cfg.light_samples, cfg.light_rule, device=device)
        basis_w = (real_sh(wi, cfg.degree) * weights[:, None]).float()  # (M, C)
        transport = _transport(material, wi.float(), cfg.precision)
        m, c = wi.shape[0], basis_w.shape[1]
        local = view_bin_directions(cfg.view_theta, cfg.view_phi, device=device).reshape(-1, 3)  # (B, 3)
        n_bins, n_vert = local.shape[0], pts.shape[0]
        n_pairs = n_vert * n_bins
        pair_chunk = max(1, cfg.batch_size // m)
        out = torch.empty(n_pairs, c, 3, dtype=torch.float32, device=device)

        chunks = range(0, n_pairs, pair_chunk)
        if progress:
            from rich.progress import track
            chunks = track(chunks, description=f"SH PRT ({n_vert} vertices x {n_bins} views x {m} lights)")
        with torch.no_grad():
            for p0 in chunks:
                p = torch.arange(p0, min(p0 + pair_chunk, n_pairs), device=device)
                v, k = p // n_bins, p % n_bins
                wo = to_world(local[k], t[v], b[v], nrm[v])
                val = transport(pts[v], nrm[v], wo / wo.norm(dim=-1, keepdim=True))  # (P, M, 3)
                # Eq. 10 for the whole chunk as one GEMM, float32 sums of M terms (relative error ~1e-6)
                out[p0:p0 + len(p)] = torch.matmul(val.transpose(1, 2), basis_w).transpose(1, 2)
        check_finite(out, "material.eval projections")
        coeffs = out.reshape(n_vert, cfg.view_theta, cfg.view_phi, c, 3)
        return cls(coeffs, pts, nrm, cfg, faces=faces)

    # ---- lighting and rendering (Eqs. 9, 11) -------------------------------------------------------------------
    def light_coefficients(self, env: EnvironmentMap | Light | Callable[[torch.Tensor], torch.Tensor],
                           samples: int = 4096, rule: str = "gauss", texel_nodes: int | None = None) -> torch.Tensor:
        """b_lm (C, 3) of a distant environment at this table's degree (Eq. 9); see `sh_light_coefficients`."""
        return sh_light_coefficients(env, self.degree, samples, rule, texel_nodes).to(self.device)

    def coefficients_at(self, vertex_index: torch.Tensor, wo: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """a_lm (N, C, 3) bilinearly interpolated over the view bins at object-space wo (N, 3) of the vertices
        `vertex_index` (N,), and a mask (N,) of wo above the vertex's horizon (a is 0 elsewhere)."""
        vi = self._check_index(vertex_index, "vertex_index")
        n = vi.shape[0]
        check_directions(wo, "wo")
        check_shape(wo, "wo", (n, 3))
        vi, w = vi.to(self.device), wo.to(self.device, torch.float32)
        nrm = self.normals[vi]
        t, b = frame_from_normal(nrm)
        loc = to_local(w, t, b, nrm)
        above = loc[:, 2] > 0
        nt, nphi = self.config.view_theta, self.config.view_phi
        s = ((1 - loc[:, 2].clamp(0, 1)) * nt - 0.5).clamp(0, nt - 1)
        phi = torch.remainder(torch.atan2(loc[:, 1], loc[:, 0]), 2 * math.pi)
        r = phi * (nphi / (2 * math.pi)) - 0.5
        i0 = s.floor().long().clamp(0, nt - 1)
        i1 = (i0 + 1).clamp(max=nt - 1)
        fs = (s - i0).clamp(0, 1)[:, None, None]
        j0f = r.floor()
        fr = (r - j0f).clamp(0, 1)[:, None, None]
        j0 = torch.remainder(j0f.long(), nphi)
        j1 = torch.remainder(j0 + 1, nphi)
        a = self.coefficients
        out = ((1 - fs) * ((1 - fr) * a[vi, i0, j0] + fr * a[vi, i0, j1])
               + fs * ((1 - fr) * a[vi, i1, j0] + fr * a[vi, i1, j1]))
        return out * above[:, None, None], above

    def radiance(self, vertex_index: torch.Tensor, wo: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        """L(x_v, wo) = sum_lm a_lm(x_v, wo) b_lm per RGB channel (Eq. 11), (N, 3) in wo's dtype; a_lm is
        bilinear over the view bins (see the module docstring); 0 where wo is below the vertex's horizon."""
        bb = self._check_b(b)
        a, _ = self.coefficients_at(vertex_index, wo)
        return (a * bb[None]).sum(1).to(wo.dtype)

    def radiance_barycentric(self, vertex_indices: torch.Tensor, bary: torch.Tensor, wo: torch.Tensor,
                             b: torch.Tensor) -> torch.Tensor:
        """Radiance (N, 3) at points inside triangles: sum_k bary_k radiance(vertex_indices[:, k], wo, b), with
        vertex_indices (N, 3) long and barycentric weights bary (N, 3)."""
        vi = self._check_index(vertex_indices, "vertex_indices", (-1, 3))
        check_shape(bary, "bary", (vi.shape[0], 3))
        if not bary.is_floating_point():
            raise InputError(f"bary: expected a floating-point tensor, got {bary.dtype}")
        check_finite(bary, "bary")
        check_shape(wo, "wo", (vi.shape[0], 3))
        bb = self._check_b(b)
        out = torch.zeros(vi.shape[0], 3, dtype=torch.float32, device=self.device)
        bw = bary.to(self.device, torch.float32)
        for k in range(3):
            a, _ = self.coefficients_at(vi[:, k], wo)
            out += bw[:, k:k + 1] * (a * bb[None]).sum(1)
        return out.to(wo.dtype)

    def _check_index(self, idx, name: str, shape: tuple = (-1,)) -> torch.Tensor:
        check_shape(idx, name, shape)
        if idx.is_floating_point() or idx.is_complex() or idx.dtype == torch.bool:
            raise InputError(f"{name}: expected an integer (long) tensor of vertex indices, got {idx.dtype}")
        if idx.numel() and (int(idx.min()) < 0 or int(idx.max()) >= self.num_vertices):
            raise InputError(f"{name}: vertex indices must lie in [0, {self.num_vertices}), got "
                             f"[{int(idx.min())}, {int(idx.max())}]")
        return idx.long()

    def _check_b(self, b) -> torch.Tensor:
        check_shape(b, "b", (self.num_coefficients, 3))
        check_finite(b, "b")
        return b.to(self.device, torch.float32)

    # ---- files -----------------------------------------------------------------------------------------------
    def save(self, path: str | Path) -> Path:
        """Write a safetensors file (coefficients, points, normals float32, faces int64 if any; the config in the
        JSON metadata)."""
        from neumat.core.version import __version__
        tensors = {"coefficients": self.coefficients.float(), "points": self.points.float(),
                   "normals": self.normals.float()}
        if self.faces is not None:
            tensors["faces"] = self.faces.long()
        return write_tagged(path, tensors, {"type": FILE_TYPE, "config": asdict(self.config),
                                            "neumat_version": __version__})

    @classmethod
    def load(cls, path: str | Path, device=None) -> "SHPRT":
        """Read a file written by `save`; wrong or inconsistent files raise DataFormatError."""
        meta, tensors = read_tagged(path, FILE_TYPE, "SH PRT")
        try:
            known = {f.name for f in fields(PRTConfig)}
            cfg = PRTConfig(**{k: v for k, v in meta["config"].items() if k in known})
            faces = tensors.get("faces")
            return cls(tensors["coefficients"].to(device), tensors["points"].to(device),
                       tensors["normals"].to(device), cfg, None if faces is None else faces.to(device))
        except KeyError as e:
            raise DataFormatError(f"{path}: missing field {e}") from None
        except (InputError, TypeError, AttributeError) as e:
            raise DataFormatError(f"{path}: inconsistent SH PRT file: {e}") from None


def _check_vertices(points, normals) -> None:
    check_shape(points, "points", (-1, 3))
    if not points.is_floating_point():
        raise InputError(f"points: expected a floating-point tensor, got {points.dtype}")
    check_finite(points, "points")
    if points.shape[0] < 1:
        raise InputError("points: expected at least one vertex")
    check_shape(normals, "normals", (points.shape[0], 3))
    if not normals.is_floating_point():
        raise InputError(f"normals: expected a floating-point tensor, got {normals.dtype}")
    check_directions(normals, "normals")


def _check_faces(faces, n_vertices: int) -> torch.Tensor:
    check_shape(faces, "faces", (-1, 3))
    if faces.is_floating_point() or faces.is_complex() or faces.dtype == torch.bool:
        raise InputError(f"faces: expected an integer tensor of vertex indices, got {faces.dtype}")
    if faces.numel() and (int(faces.min()) < 0 or int(faces.max()) >= n_vertices):
        raise InputError(f"faces: vertex indices must lie in [0, {n_vertices}), got "
                         f"[{int(faces.min())}, {int(faces.max())}]")
    return faces.long()


# ---- S_hat for every (vertex, view) pair and every light direction ---------------------------------------------
def _transport(material, wi: torch.Tensor, precision: str = "fp32"
               ) -> Callable[[torch.Tensor, torch.Tensor, torch.Tensor], torch.Tensor]:
    """A function (x, n, wo) (P, 3) each -> S_hat (P, M, 3) float32 at the M light directions wi (M, 3), evaluated
    in `precision` ("fp32", or "bf16" for NeuPreSS only)."""
    from neumat.methods.neupress.model import NeuPreSS
    if isinstance(material, NeuPreSS):
        return _SeparableNeuPreSS(material, wi, precision)
    if precision != "fp32":
        # autocast would round inputs such as Fourier-feature angles (up to ~100 rad) to 8 bits: wrong, not fast
        raise InputError(f"PRTConfig.precision: {precision!r} is for NeuPreSS models (their features are built in "
                         f"float32 before the bfloat16 network); {type(material).__name__} needs \"fp32\"")
    return _QueryTransport(material, wi)


class _QueryTransport:
    """Any material: one `eval(Query)` of P M queries."""

    def __init__(self, material, wi: torch.Tensor) -> None:
        self.material, self.wi = material, wi

    def __call__(self, x: torch.Tensor, n: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
        p, m = x.shape[0], self.wi.shape[0]
        q = Query.trusted(wi=self.wi.repeat(p, 1), wo=wo.repeat_interleave(m, 0), x=x.repeat_interleave(m, 0),
                          n=n.repeat_interleave(m, 0))
        val = self.material.eval(q)
        if not isinstance(val, torch.Tensor) or tuple(val.shape) != (p * m, 3):
            raise InputError(f"material.eval: expected a ({p * m}, 3) tensor, got {tuple(getattr(val, 'shape', ()))}")
        return val.float().reshape(p, m, 3)


class _SeparableNeuPreSS:
    """NeuPreSS's S_hat = relu(MLP(F(v))) with the Fourier features F(v) = [cos a, sin a], a = 2 pi G v, built
    without per-query encodings or transcendentals: v = (enc(wi), enc(wo), pos(x)) and G v is linear, so
    a = a_light(wi) + a_pair(wo, x), and cos a, sin a follow from the cosines and sines of the two parts (computed
    once per light direction and once per (vertex, view) pair) by the angle-addition formulas. Equal to
    `NeuPreSS.eval` up to float32 rounding (tests/methods/neupress/test_neupress_prt.py). For "bf16" the angle addition
    and the MLP (a bfloat16 copy of its weights) run in bfloat16."""

    def __init__(self, model, wi: torch.Tensor, precision: str = "fp32") -> None:
        self.model = model
        self.mlp_dtype = torch.bfloat16 if precision == "bf16" else model.box_min.dtype
        self.mlp = copy.deepcopy(model.appearance).to(self.mlp_dtype) if precision == "bf16" else model.appearance
        g = model.appearance_features.G  # (F, 2 d + 3)
        self.d = (g.shape[1] - 3) // 2
        self.g_wo, self.g_x = g[:, self.d:2 * self.d].T, g[:, 2 * self.d:].T
        dtype = model.box_min.dtype
        a = (2 * math.pi) * (model._direction(wi.to(g.device, dtype)) @ g[:, :self.d].T)  # (M, F)
        self.cos_l, self.sin_l = torch.cos(a)[None].to(self.mlp_dtype), torch.sin(a)[None].to(self.mlp_dtype)

    def __call__(self, x: torch.Tensor, n: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
        model, dtype = self.model, self.model.box_min.dtype
        a = (2 * math.pi) * (model._direction(wo.to(dtype)) @ self.g_wo + model._position(x.to(dtype)) @ self.g_x)
        cos_p, sin_p = torch.cos(a)[:, None].to(self.mlp_dtype), torch.sin(a)[:, None].to(self.mlp_dtype)  # (P, 1, F)
        p, m, f = a.shape[0], self.cos_l.shape[1], a.shape[1]
        feat = torch.empty(p, m, 2 * f, dtype=self.mlp_dtype, device=a.device)
        c, s = feat[..., :f], feat[..., f:]
        torch.mul(cos_p, self.cos_l, out=c)  # cos(a_p + a_l) = cos a_p cos a_l - sin a_p sin a_l
        c.sub_(sin_p * self.sin_l)
        torch.mul(sin_p, self.cos_l, out=s)  # sin(a_p + a_l) = sin a_p cos a_l + cos a_p sin a_l
        s.add_(cos_p * self.sin_l)
        return torch.relu(self.mlp(feat.reshape(p * m, 2 * f))).float().reshape(p, m, 3)
