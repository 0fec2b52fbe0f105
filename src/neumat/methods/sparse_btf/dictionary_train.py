"""Training of SparseBTF dictionary ensembles (Kavoosi et al. 2023, Sec. 3.2, Eq. 2): HOSVD initialisation
from a random partition of the data points, then iterations of sparse coding / assignment and orthogonal
Procrustes updates (`neumat.methods.sparse_btf.dictionary` describes the algorithm and holds the representation:
projection, coding, reconstruction, `Ensemble`, `BTFDictionary` files).

The pieces are shared by two callers:
- `train_dictionary` / `train_ensemble`: train once on a few BTFs (`neumat fit-dictionary`), running
  iterations until `max_iters` or until the objective's relative decrease falls below `tol`;
- the "dictionary" phase of the sparse-btf recipe (`neumat.methods.sparse_btf.train`), one trainer step per
  iteration (`ensemble_iteration`), so that a checkpoint between iterations resumes bit for bit.

Defaults (K, tau_l, patch, log_eps from `neumat.methods.sparse_btf.model.Config`; iterations, tol, fraction and
seed from the sparse-btf RECIPE) live there, not here.
"""
from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, field

import torch

from neumat.core.errors import InputError
from neumat.methods.sparse_btf.dictionary import (BTFDictionary, Codes, Ensemble, code_points, dense_coefficients,
                                        mode_product, prepare_btf)


def _recipe_defaults() -> dict:
    """iterations, tol, fraction, seed of the sparse-btf recipe (the one place these defaults live)."""
    from neumat.fit.method import recipe_for, typed_options
    r = recipe_for("sparse-btf")
    o = typed_options("sparse-btf", r.options)
    return {"iterations": max(r.steps - 1, 0), "tol": o.tol, "fraction": o.fraction, "seed": r.seed}


def hosvd_bases(x: torch.Tensor) -> list[torch.Tensor]:
    """Orthonormal bases (m_n, m_n) of the mode-n unfoldings of x (N, m1, ..., m4) (HOSVD factors)."""
    mats = []
    for n in range(1, x.dim()):
        unf = x.movedim(n, 1).reshape(x.shape[0], x.shape[n], -1)
        gram = torch.einsum("nar,nbr->ab", unf, unf)
        _, vecs = torch.linalg.eigh(gram.double())
        mats.append(vecs.flip(-1).to(x.dtype))
    return mats


def procrustes(a: torch.Tensor) -> torch.Tensor:
    """The orthonormal U maximising tr(U^T a), i.e. the polar factor of a (m, m)."""
    u, _, vh = torch.linalg.svd(a.double())
    return (u @ vh).to(a.dtype)


@dataclass
class TrainingLog:
    """Objective (sum of squared errors) after every iteration, seconds, and iterations run."""

    objective: list[float] = field(default_factory=list)
    seconds: float = 0.0
    iterations: int = 0


def check_points(x: torch.Tensor, num_dictionaries: int, tau: int) -> None:
    if x.dim() != 5:
        raise InputError(f"train_ensemble x: expected data points (N, m1, m2, m3, m4), got {tuple(x.shape)}")
    n = x.shape[0]
    if num_dictionaries < 1 or num_dictionaries > n:
        raise InputError(f"train_ensemble: need 1 <= K <= number of data points ({n}), got K = {num_dictionaries}")
    if tau < 1:
        raise InputError(f"train_ensemble tau: expected >= 1, got {tau}")


def init_ensemble(x: torch.Tensor, num_dictionaries: int, generator: torch.Generator) -> Ensemble:
    """The initial ensemble: the points x (N, m1..m4) split into K groups by a random permutation drawn with
    `generator`, and the HOSVD bases of every group."""
    n = x.shape[0]
    groups = torch.randperm(n, generator=generator, device=generator.device).to(x.device) % num_dictionaries
    init = [hosvd_bases(x[groups == k]) for k in range(num_dictionaries)]
    return Ensemble([torch.stack([d[j] for d in init]) for j in range(4)])


def objective(codes: Codes, shape: tuple[int, ...]) -> float:
    """Sum of squared errors of the codes (Eq. 2's objective)."""
    return float(codes.error.sum()) * math.prod(shape)


def has_converged(previous: float, current: float, tol: float) -> bool:
    """Whether an iteration lowered the objective by at most `tol` relative to `previous` (training stops)."""
    return previous - current <= tol * abs(previous)


def ensemble_iteration(x: torch.Tensor, ens: Ensemble, tau: int, codes: Codes) -> Codes:
    """One training iteration of `ens` on points x (N, m1..m4), in place (ens.mats may be views of a model's
    buffers): for every dictionary and mode the Procrustes update followed by re-coding its members, then
    the codes of all points. `codes` = code_points(x, ens, tau) on entry; returns the codes on exit."""
    n, num_dictionaries = x.shape[0], ens.size
    shape = ens.shape
    chunk = max(1, (1 << 25) // math.prod(shape))         # points per chunk of the dictionary update (memory)
    for k in range(num_dictionaries):
        sel = codes.membership == k
        if not bool(sel.any()):
            # re-seed an empty dictionary from the worst-represented points
            worst = codes.error.topk(max(1, n // num_dictionaries)).indices
            for j, u in enumerate(hosvd_bases(x[worst])):
                ens.mats[j][k] = u
            continue
        xk, members = x[sel], _subset(codes, sel)
        for mode in range(1, 5):
            mats = ens.dictionary(k)
            cross = torch.zeros(shape[mode - 1], shape[mode - 1], dtype=x.dtype, device=x.device)
            for lo in range(0, xk.shape[0], chunk):          # sum over members of z_(n) s_(n)^T
                part = slice(lo, lo + chunk)
                s = dense_coefficients(_subset(members, part), shape)
                z = xk[part]
                for j, u in enumerate(mats, start=1):
                    if j != mode:
                        z = mode_product(z, u.T, j)
                zn = z.movedim(mode, 1).reshape(z.shape[0], shape[mode - 1], -1)
                sn = s.movedim(mode, 1).reshape(s.shape[0], shape[mode - 1], -1)
                cross += torch.einsum("nar,nbr->ab", zn, sn)
            ens.mats[mode - 1][k] = procrustes(cross)
            sub = code_points(xk, Ensemble([u[k:k + 1] for u in ens.mats]), tau)
            _assign(codes, sel, sub, k)
            members = sub                                    # = _subset(codes, sel) up to membership
    return code_points(x, ens, tau)


def train_ensemble(x: torch.Tensor, num_dictionaries: int, tau: int, max_iters: int | None = None,
                   tol: float | None = None, seed: int | None = None, progress: bool = False,
                   description: str = "training dictionaries") -> tuple[Ensemble, TrainingLog]:
    """Train an ensemble of `num_dictionaries` orthonormal 4D dictionaries on data points x (N, m1..m4) with
    training sparsity `tau` (tau_l), alternating coding/assignment and Procrustes updates (module docstring).
    max_iters, tol, seed: default the sparse-btf recipe's (steps - 1, option tol, seed)."""
    defaults = _recipe_defaults()
    max_iters = defaults["iterations"] if max_iters is None else max_iters
    tol = defaults["tol"] if tol is None else tol
    seed = defaults["seed"] if seed is None else seed
    check_points(x, num_dictionaries, tau)
    t0 = time.perf_counter()
    ens = init_ensemble(x, num_dictionaries, torch.Generator().manual_seed(seed))
    log = TrainingLog()
    steps = range(max_iters)
    if progress:
        from rich.progress import track
        steps = track(steps, description=description)
    codes = code_points(x, ens, tau)
    for _ in steps:
        codes = ensemble_iteration(x, ens, tau, codes)
        obj = objective(codes, ens.shape)
        log.objective.append(obj)
        log.iterations += 1
        if len(log.objective) > 1 and has_converged(log.objective[-2], obj, tol):
            break
    log.seconds = time.perf_counter() - t0
    return ens, log


def _subset(codes: Codes, sel) -> Codes:
    return Codes(codes.membership[sel], codes.values[sel], codes.index[sel], codes.counts[sel], codes.error[sel])


def _assign(codes: Codes, sel: torch.Tensor, sub: Codes, k: int) -> None:
    codes.values[sel] = sub.values
    codes.index[sel] = sub.index
    codes.counts[sel] = sub.counts
    codes.error[sel] = sub.error
    codes.membership[sel] = k


#: data points per dictionary in the paper's training set (2880 points for K = 8, Sec. 4)
PAPER_POINTS_PER_DICTIONARY = 360


def training_size_warning(n_points: int, num_dictionaries: int, tau_train: tuple[int, ...],
                          shape: tuple[int, int, int, int]) -> str | None:
    """Why `n_points` data points of shape (p, p, L, V) are too few to train `num_dictionaries` (K) dictionaries
    at training sparsities `tau_train` (tau_l per channel), or None when they are not.

    Rule, per dictionary (a random partition gives each about n_points / K members):
    - floor: a member's sparse coefficients give the mode-n Procrustes update at most min(tau_l, m_n) directions,
      so fewer than max_n m_n / min(tau_l, m_n) members leave basis directions no training point constrains
      (the smallest tau_l counts);
    - the paper's ratio: at least `PAPER_POINTS_PER_DICTIONARY` (360) members, the training set the paper's
      results come from (benchmarks/studies/btf/results/btf_vs_pca.md, section 14, measures the SparseBTF / PCA ratio
      from 75 to 2880 points at 17 x 17 directions).
    """
    per = n_points / num_dictionaries
    tau = min(tau_train)
    floor = math.ceil(max(m / min(tau, m) for m in shape))
    least = max(floor, PAPER_POINTS_PER_DICTIONARY)
    if per >= least:
        return None
    why = (f"below the floor of {floor} (max_n m_n / min(tau_l, m_n) for data points {tuple(shape)}, tau_l "
           f"{tau}): some basis directions get no training coefficient" if per < floor else
           f"below the paper's {PAPER_POINTS_PER_DICTIONARY} (2880 points for K = 8)")
    fewer = f" or fewer dictionaries (K <= {n_points // least})" if n_points >= least else ""
    return (f"{n_points} training data points for K = {num_dictionaries} dictionaries is {per:.0f} per dictionary, "
            f"{why}. Use about {num_dictionaries * least} points (more or larger BTFs, a larger --fraction){fewer}. "
            "Measured at 17 x 17 directions, 120 x 120 texels: 75 points coded unseen BTFs about as well as "
            "2880 (docs/btf.md, 'Training-set size'); untested at larger direction sets")


def keep_count(n: int, num_dictionaries: int, fraction: float) -> int:
    """Data points kept of n by a sample `fraction` (at least one per dictionary)."""
    if not 0 < fraction <= 1:
        raise InputError(f"sample fraction: expected a number in (0, 1], got {fraction!r}")
    return max(num_dictionaries, round(n * fraction))


def train_dictionary(btfs: list, num_dictionaries: int | None = None,
                     tau_train: tuple[int, int, int] | None = None, patch: int | None = None,
                     log_eps: float | None = None, sample_fraction: float | None = None,
                     max_iters: int | None = None, tol: float | None = None, seed: int | None = None,
                     progress: bool = False, statistics: str = "image") -> BTFDictionary:
    """Train the Y, U and V ensembles once on a few BTFs (TabulatedBTF objects of one direction set).

    sample_fraction: the random fraction of data points used (the paper: 10%). statistics: the standardisation
    of the training points (SparseBTF Config.statistics; recorded in info["statistics"]). Warns when the kept points are
    too few for K (`training_size_warning`); refuses BTFs whose texels do not split into patches. Defaults:
    num_dictionaries, tau_train, patch, log_eps from `neumat.methods.sparse_btf.model.Config`; sample_fraction,
    max_iters, tol, seed from the sparse-btf recipe.
    """
    from neumat.methods.sparse_btf.model import Config
    cfg, defaults = Config(), _recipe_defaults()
    num_dictionaries = cfg.num_dictionaries if num_dictionaries is None else num_dictionaries
    tau_train = tuple(cfg.tau_train if tau_train is None else tau_train)
    patch = cfg.patch if patch is None else patch
    log_eps = cfg.log_eps if log_eps is None else log_eps
    sample_fraction = defaults["fraction"] if sample_fraction is None else sample_fraction
    seed = defaults["seed"] if seed is None else seed
    if not btfs:
        raise InputError("train_dictionary: expected at least one BTF")
    first = btfs[0]
    for b in btfs[1:]:
        if b.light_dirs.shape != first.light_dirs.shape or b.view_dirs.shape != first.view_dirs.shape or \
                float((b.light_dirs - first.light_dirs).abs().max()) > 1e-4 or \
                float((b.view_dirs - first.view_dirs).abs().max()) > 1e-4:
            raise InputError(f"train_dictionary: BTF {b.label!r} has another direction set than {first.label!r}")
    if not 0 < sample_fraction <= 1:
        raise InputError(f"train_dictionary sample_fraction: expected (0, 1], got {sample_fraction}")
    for b in btfs:
        h, w = b.data.shape[2:4]
        if h % patch or w % patch:
            raise InputError(f"train_dictionary: BTF {b.label!r} has {h} x {w} texels, which do not split into the "
                             f"dictionary's {patch} x {patch} patches; generate it at a multiple of {patch} texels "
                             f"(`neumat data btf-generate --size {max(patch, h // patch * patch)}`) or a patch "
                             f"size (--patch) dividing {h} and {w}")
    counts = [(b.data.shape[2] // patch) * (b.data.shape[3] // patch) for b in btfs]
    n = sum(counts)
    gen = torch.Generator().manual_seed(seed)
    keep = torch.randperm(n, generator=gen)[:keep_count(n, num_dictionaries, sample_fraction)]
    too_few = training_size_warning(len(keep), num_dictionaries, tau_train, (patch, patch, *first.data.shape[:2]))
    if too_few:
        warnings.warn(f"train_dictionary: {too_few}", stacklevel=2)
    points = torch.empty(3, len(keep), patch, patch, *first.data.shape[:2], device=first.data.device)
    start = 0
    for b, count in zip(btfs, counts):                 # one BTF at a time: only the kept points are held
        pos = ((keep >= start) & (keep < start + count)).nonzero()[:, 0]
        prepared = prepare_btf(b.data, patch, log_eps, statistics)[0]
        points[:, pos.to(points.device)] = prepared[:, (keep[pos] - start).to(points.device)]
        start += count
    ensembles, info = [], {"objective": {}, "seconds": {}, "iterations": {}, "points": len(keep),
                           "btfs": [b.label for b in btfs], "statistics": statistics}
    for c, ch in enumerate("YUV"):
        ens, log = train_ensemble(points[c], num_dictionaries, tau_train[c], max_iters, tol,
                                  seed + c, progress, f"training {ch} dictionaries")
        ensembles.append(ens)
        info["objective"][ch], info["seconds"][ch], info["iterations"][ch] = log.objective, log.seconds, log.iterations
    return BTFDictionary(ensembles, first.light_dirs.clone(), first.view_dirs.clone(), patch, tuple(tau_train),
                         log_eps, info)
