"""Chi-square goodness-of-fit test of a sampler against its density (after Mitsuba's `ChiSquareTest`).

Samples are histogrammed over an equal-measure grid of a 2D parameterisation of the domain: (cos theta,
phi) for directions, (x, y) for the unit square, (r^2, phi) for the unit disk. Expected counts integrate the
density over each cell with Gauss-Legendre quadrature; cells with expected count < 5 are pooled. Invalid
samples (sample_fn says so) form one extra cell whose expected count is the density mass missing from the
domain, so a sampler that drops mass its pdf still claims is caught too.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable

import numpy as np
import torch
from scipy import stats

from ..core.errors import InputError
from ..core.query import Query

_BATCH = 1 << 18
_CHECK_BATCH = 4096  # samples on which chi2_material compares sample().pdf with pdf()


@dataclass
class Chi2Result:
    """Outcome of a chi-square test; truthy when the test passed."""

    passed: bool
    p_value: float
    statistic: float
    dof: int
    pdf_integral: float
    message: str

    def __bool__(self) -> bool:
        return self.passed


@dataclass
class _Param:
    """A 2D parameterisation of a domain: (s, t) in [s0, s1] x [t0, t1] with constant measure `jac`."""

    s_range: tuple[float, float]
    t_range: tuple[float, float]
    jac: float
    to_st: Callable[[torch.Tensor], tuple[torch.Tensor, torch.Tensor]]
    from_st: Callable[[torch.Tensor, torch.Tensor], torch.Tensor]
    names: tuple[str, str]


def _phi(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    return torch.remainder(torch.atan2(y, x), 2 * math.pi)


def _direction_param(sphere: bool) -> _Param:
    def from_st(z, phi):
        r = (1 - z * z).clamp(min=0).sqrt()
        return torch.stack([r * torch.cos(phi), r * torch.sin(phi), z], -1)

    return _Param((-1.0 if sphere else 0.0, 1.0), (0.0, 2 * math.pi), 1.0,
                  lambda w: (w[:, 2], _phi(w[:, 0], w[:, 1])), from_st, ("cos theta", "phi"))


def _square_param() -> _Param:
    return _Param((0.0, 1.0), (0.0, 1.0), 1.0, lambda p: (p[:, 0], p[:, 1]),
                  lambda x, y: torch.stack([x, y], -1), ("x", "y"))


def _disk_param() -> _Param:
    def from_st(r2, phi):
        r = r2.clamp(min=0).sqrt()
        return torch.stack([r * torch.cos(phi), r * torch.sin(phi)], -1)

    return _Param((0.0, 1.0), (0.0, 2 * math.pi), 0.5,
                  lambda p: ((p * p).sum(-1), _phi(p[:, 0], p[:, 1])), from_st, ("r^2", "phi"))


def chi2_directions(sample_fn, pdf_fn, n_samples: int = 1_000_000, res: tuple[int, int] = (40, 80),
                    sphere: bool = False, alpha: float = 0.01, n_tests: int = 1, seed: int = 0,
                    dump_dir: str | os.PathLike | None = None, quad: int = 6,
                    dtype: torch.dtype = torch.float32, device=None) -> Chi2Result:
    """Test a direction sampler against its solid-angle density.

    sample_fn(u (N, 2)) -> (w (N, 3), valid (N,) bool); pdf_fn(w (M, 3)) -> (M,) density per steradian.
    res = (cells in cos theta, cells in phi); sphere=False restricts the domain to z >= 0. The test fails
    at significance alpha with the Sidak correction for a family of `n_tests` tests.
    """
    return _run(sample_fn, pdf_fn, _direction_param(sphere), n_samples, res, alpha, n_tests, seed,
                dump_dir, quad, dtype, device)


def chi2_2d(sample_fn, pdf_fn, n_samples: int = 1_000_000, res: tuple[int, int] = (40, 40),
            domain: str = "square", alpha: float = 0.01, n_tests: int = 1, seed: int = 0,
            dump_dir: str | os.PathLike | None = None, quad: int = 6,
            dtype: torch.dtype = torch.float32, device=None) -> Chi2Result:
    """Test a warp onto the unit square ("square", cells in x, y) or unit disk ("disk", cells in r^2, phi).

    sample_fn(u (N, 2)) -> p (N, 2) or (p, valid (N,) bool); pdf_fn(p (M, 2)) -> (M,) density per unit area.
    """
    params = {"square": _square_param, "disk": _disk_param}
    if domain not in params:
        raise InputError(f"domain: expected one of {sorted(params)}, got {domain!r}")
    return _run(sample_fn, pdf_fn, params[domain](), n_samples, res, alpha, n_tests, seed, dump_dir, quad,
                dtype, device)


def chi2_material(material, wi: torch.Tensor, n_samples: int = 1_000_000, template: Query | None = None,
                  pdf_rtol: float = 1e-3, **kw) -> Chi2Result:
    """Test `material.sample` against `material.pdf` for one incident direction wi (3,).

    template: optional one-row Query whose other fields (uv, footprint, lod, x) are repeated for every
    sample (spatially varying materials). Samples with pdf 0 count as invalid. Other keywords go to
    `chi2_directions`; the domain is the whole sphere (`sphere=True`, `res` = (80, 80) cells, 40 per
    hemisphere in cos theta) unless `sphere=False` is given: a BRDF sampler may send glossy samples below the
    horizon with their pdf, and one that does not puts no mass there, so the sphere tests every sampler. The
    test also fails when the pdf that `sample` returns differs from `pdf(wo)` by more than `pdf_rtol`
    (relative) on a check batch.
    """
    if not getattr(material, "can_sample", False):
        raise InputError(f"material: {type(material).__name__} cannot sample (can_sample = False)")
    if not isinstance(wi, torch.Tensor) or wi.shape != (3,):
        raise InputError(f"wi: expected a torch.Tensor of shape (3,), got {getattr(wi, 'shape', type(wi))}")
    if template is not None and len(template) != 1:
        raise InputError(f"template: expected a one-row Query, got {len(template)} rows")
    kw.setdefault("sphere", True)
    kw.setdefault("res", (80, 80) if kw["sphere"] else (40, 80))
    kw.setdefault("dtype", wi.dtype)
    kw.setdefault("device", wi.device)

    def query(n: int, wo: torch.Tensor | None) -> Query:
        base = {} if template is None else {k: getattr(template, k) for k in ("uv", "footprint", "lod", "x")}
        extra = {k: v.expand(n, *v.shape[1:]) for k, v in base.items() if v is not None}
        return Query(wi=wi.expand(n, 3), wo=wo, **extra)

    def sample_fn(u):
        s = material.sample(query(u.shape[0], None), u)
        return s.wo, s.pdf > 0

    def pdf_fn(w):
        return material.pdf(query(w.shape[0], w))

    result = chi2_directions(sample_fn, pdf_fn, n_samples=n_samples, **kw)
    gen = torch.Generator(device="cpu").manual_seed(kw.get("seed", 0) + 1)
    u = torch.rand(_CHECK_BATCH, 2, generator=gen, dtype=torch.float64).to(dtype=kw["dtype"], device=kw["device"])
    s = material.sample(query(_CHECK_BATCH, None), u)
    ok = s.pdf > 0
    if bool(ok.any()):
        ref = pdf_fn(s.wo[ok])
        err = ((s.pdf[ok] - ref).abs() / ref.abs().clamp(min=1e-12)).max().item()
        if err > pdf_rtol:
            problem = f"FAILED: sample().pdf differs from pdf(wo) by up to {err:.3g} (relative) > {pdf_rtol}"
            result = replace(result, passed=False, message=f"{problem}; {result.message.removeprefix('FAILED: ')}")
    return result


def _run(sample_fn, pdf_fn, param: _Param, n_samples, res, alpha, n_tests, seed, dump_dir, quad, dtype,
         device) -> Chi2Result:
    """Histogram, integrate, pool and test; shared by the public entry points."""
    if n_samples < 1:
        raise InputError(f"n_samples: expected a positive count, got {n_samples}")
    if len(res) != 2 or min(res) < 1:
        raise InputError(f"res: expected two positive cell counts, got {res}")
    if not 0 < alpha < 1 or n_tests < 1:
        raise InputError(f"alpha / n_tests: expected 0 < alpha < 1 and n_tests >= 1, got {alpha}, {n_tests}")
    observed, n_invalid, n_outside = _histogram(sample_fn, param, n_samples, res, seed, dtype, device)
    density = _integrate(pdf_fn, param, res, quad, dtype, device)  # pdf mass per cell
    integral = float(density.sum())
    expected = density * n_samples
    obs = np.append(observed.ravel(), n_invalid).astype(np.float64)
    exp = np.append(expected.ravel(), max(n_samples * (1 - integral), 0.0))
    threshold = 1 - (1 - alpha) ** (1 / n_tests)
    stat, dof, problem = _pooled_chi2(obs, exp)
    if problem is None and n_outside:
        problem = f"{n_outside} valid sample(s) fell outside the domain"
    if problem is None and integral > 1 + 1e-3:
        problem = f"pdf integrates to {integral:.6f} > 1"
    p_value = 0.0 if problem is not None else float(stats.chi2.sf(stat, dof)) if dof > 0 else 1.0
    passed = problem is None and p_value >= threshold
    message = (f"chi2 = {stat:.4g}, dof = {dof}, p = {p_value:.4g} (threshold {threshold:.3g}), "
               f"pdf integral = {integral:.6f}, invalid samples = {n_invalid}/{n_samples}")
    if problem is not None:
        message = f"{problem}; {message}"
    if not passed:
        message = "FAILED: " + message
        target = dump_dir if dump_dir is not None else os.environ.get("NEUMAT_CHI2_DUMP")
        if target:
            message += "; " + _dump(Path(target), observed, expected, param)
    return Chi2Result(passed, p_value, float(stat), int(dof), integral, message)


def _histogram(sample_fn, param: _Param, n_samples, res, seed, dtype, device):
    """Counts (res) of valid samples, number of invalid ones, number of valid ones outside the domain."""
    gen = torch.Generator(device="cpu").manual_seed(seed)
    counts = torch.zeros(res[0] * res[1], dtype=torch.float64)
    n_invalid = n_outside = 0
    (s0, s1), (t0, t1) = param.s_range, param.t_range
    for start in range(0, n_samples, _BATCH):
        n = min(_BATCH, n_samples - start)
        u = torch.rand(n, 2, generator=gen, dtype=torch.float64).to(dtype=dtype, device=device)
        out = sample_fn(u)
        x, valid = (out if isinstance(out, tuple) else (out, None))
        x = x.detach().to("cpu", torch.float64)
        valid = torch.ones(n, dtype=torch.bool) if valid is None else valid.detach().to("cpu").bool()
        valid &= torch.isfinite(x).all(-1)
        n_invalid += int((~valid).sum())
        s, t = param.to_st(x[valid])
        eps = 1e-9
        inside = (s >= s0 - eps) & (s <= s1 + eps) & (t >= t0 - eps) & (t <= t1 + eps)
        n_outside += int((~inside).sum())
        i = ((s[inside] - s0) / (s1 - s0) * res[0]).floor().long().clamp(0, res[0] - 1)
        j = ((t[inside] - t0) / (t1 - t0) * res[1]).floor().long().clamp(0, res[1] - 1)
        counts += torch.bincount(i * res[1] + j, minlength=counts.numel()).double()
    return counts.reshape(res).numpy(), n_invalid, n_outside


def _integrate(pdf_fn, param: _Param, res, quad, dtype, device) -> np.ndarray:
    """Density integrated over each cell (res) by `quad` x `quad` Gauss-Legendre points."""
    x, w = np.polynomial.legendre.leggauss(quad)
    x, w = (x + 1) / 2, w / 2  # on [0, 1]
    (s0, s1), (t0, t1) = param.s_range, param.t_range
    ds, dt = (s1 - s0) / res[0], (t1 - t0) / res[1]
    s = torch.as_tensor(s0 + (np.arange(res[0])[:, None] + x[None]) * ds).reshape(-1)
    t = torch.as_tensor(t0 + (np.arange(res[1])[:, None] + x[None]) * dt).reshape(-1)
    ss, tt = torch.meshgrid(s, t, indexing="ij")
    pts = param.from_st(ss.reshape(-1), tt.reshape(-1))
    values = []
    for start in range(0, pts.shape[0], _BATCH):
        p = pts[start:start + _BATCH].to(dtype=dtype, device=device)
        values.append(pdf_fn(p).detach().to("cpu", torch.float64))
    v = torch.cat(values).reshape(res[0], quad, res[1], quad).numpy()
    if not np.isfinite(v).all() or (v < 0).any():
        raise InputError("pdf_fn: returned negative or non-finite densities")
    return np.einsum("iajb,a,b->ij", v, w, w) * ds * dt * param.jac


def _pooled_chi2(obs: np.ndarray, exp: np.ndarray) -> tuple[float, int, str | None]:
    """Pearson statistic and degrees of freedom, pooling cells with expected count < 5 (Mitsuba's rule)."""
    stat, dof = 0.0, 0
    pool_obs = pool_exp = 0.0
    for k in np.argsort(exp, kind="stable"):
        o, e = obs[k], exp[k]
        if e <= 0:
            if o > 0:
                return math.inf, 0, f"{int(o)} sample(s) in a cell where the pdf integrates to 0"
            continue
        if e < 5:
            pool_obs += o
            pool_exp += e
            if pool_exp >= 5:
                stat += (pool_obs - pool_exp) ** 2 / pool_exp
                dof += 1
                pool_obs = pool_exp = 0.0
        else:
            stat += (o - e) ** 2 / e
            dof += 1
    if pool_exp > 0:
        stat += (pool_obs - pool_exp) ** 2 / pool_exp
        dof += 1
    return stat, dof - 1, None


def _dump(target: Path, observed: np.ndarray, expected: np.ndarray, param: _Param) -> str:
    """Write observed / expected histograms as .npy and one PNG; returns a sentence naming the files."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    target.mkdir(parents=True, exist_ok=True)
    obs_path, exp_path, png_path = target / "chi2_observed.npy", target / "chi2_expected.npy", target / "chi2.png"
    np.save(obs_path, observed)
    np.save(exp_path, expected)
    fig, axes = plt.subplots(1, 3, figsize=(15, 4))
    vmax = max(observed.max(), expected.max())
    extent = (*param.t_range, *param.s_range)
    for ax, img, title in ((axes[0], observed, "observed"), (axes[1], expected, "expected")):
        im = ax.imshow(img, origin="lower", aspect="auto", extent=extent, vmin=0, vmax=vmax)
        fig.colorbar(im, ax=ax)
        ax.set(title=title, xlabel=param.names[1], ylabel=param.names[0])
    diff = (observed - expected) / np.sqrt(np.maximum(expected, 1.0))
    lim = max(np.abs(diff).max(), 1e-12)
    im = axes[2].imshow(diff, origin="lower", aspect="auto", extent=extent, cmap="RdBu_r", vmin=-lim, vmax=lim)
    fig.colorbar(im, ax=axes[2])
    axes[2].set(title="(obs - exp) / sqrt(exp)", xlabel=param.names[1], ylabel=param.names[0])
    fig.tight_layout()
    fig.savefig(png_path, dpi=80)
    plt.close(fig)
    return f"histograms written to {obs_path}, {exp_path} and {png_path}"
