"""The PCA-BTF solve (baseline of SparseBTF, the paper's Table 5): principal components of a BTF's Y, U, V
channels in SparseBTF's model space, and the truncated model of given ranks. `fit_pca` is the direct call
(with a precomputed `Decomposition` to try several ranks cheaply); `fit(PCABTF.for_btf(btf, ranks=...), btf)`
runs the same solve as the one-step solver phase of the trainer (recipe `neumat.methods.sparse_btf.pca_train`).
The model (`neumat.methods.sparse_btf.pca`) keeps the representation: storage, decode, eval.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch

from neumat.core.errors import InputError
from neumat.methods.sparse_btf.pca import PCABTF, Config, rank_budget
from neumat.methods.sparse_btf.dictionary import rgb_to_model_space
from neumat.reflectance.btf import TabulatedBTF
from neumat.fit.method import recipe_for, typed_options


def fit_pca(btf: TabulatedBTF, ranks: tuple[int, int, int] | None = None, log_eps: float | None = None,
            neighbours: int | None = None, decomposition: "Decomposition | None" = None,
            budget_bytes: int = 0) -> PCABTF:
    """Truncated PCA of `btf` with `ranks` components for Y, U, V, or, without ranks, the most that fit
    `budget_bytes` (0: SparseBTF's per-BTF bytes for this BTF; `budget_components`); from `decomposition`, a
    `decompose` of this BTF with enough components, when given. log_eps, neighbours default to
    `neumat.methods.sparse_btf.pca.Config`'s."""
    fields = {k: v for k, v in (("ranks", ranks), ("log_eps", log_eps), ("neighbours", neighbours)) if v is not None}
    if "ranks" in fields:
        fields["ranks"] = tuple(int(r) for r in fields["ranks"])
    model = PCABTF.for_btf(btf, **fields).to(btf.data.device)
    solve_into(model, btf, budget_bytes, decomposition)
    return model


def solve_into(model: PCABTF, btf: TabulatedBTF, budget_bytes: int = 0, decomposition: "Decomposition | None" = None,
               **decompose_options) -> "Decomposition":
    """Load `model`'s components from the principal components of `btf` (`decomposition` when given, else
    `decompose` with `decompose_options`), choosing its ranks first when it has none (the most that fit
    `budget_bytes`, split by least error); returns the decomposition. What `fit_pca` and the recipe's solver
    phase (methods/sparse_btf/pca_train.py) both run."""
    c = model.cfg
    total = max(c.ranks) if c.ranks else budget_components(c, budget_bytes)
    dec = decomposition if decomposition is not None else decompose(btf, c.log_eps, total, **decompose_options)
    if not c.ranks:
        model.set_ranks(best_ranks(dec.eigenvalues, total))
    model.load_components(dec, btf.light_dirs, btf.view_dirs)
    return dec


def budget_components(cfg: Config, budget_bytes: int = 0) -> int:
    """The most principal components (Y, U, V together) a PCA-BTF of `cfg`'s size stores in `budget_bytes` at fp16;
    0: in the per-BTF bytes of a SparseBTF of the same size at its default config and full capacity (codes and
    statistics; its dictionary ensemble is shared by many BTFs), the paper's Table 5 comparison at equal storage."""
    from neumat.methods.sparse_btf.model import Config as SparseConfig, storage_bytes

    if budget_bytes < 0:
        raise InputError(f"pca-btf budget_bytes: expected a byte count >= 0 (0: SparseBTF's), got {budget_bytes!r}")
    size = dict(n_light=cfg.n_light, n_view=cfg.n_view, height=cfg.height, width=cfg.width)
    if budget_bytes == 0:
        sparse = SparseConfig(**size)
        # SparseBTF codes whole patches: a BTF that is not a multiple of its patch has no SparseBTF size to match
        if cfg.height % sparse.patch or cfg.width % sparse.patch:
            raise InputError(f"pca-btf: a {cfg.height}x{cfg.width}-texel BTF has no SparseBTF size to match (not a "
                             f"multiple of its {sparse.patch}-texel patch); give ranks or budget_bytes")
        budget_bytes = storage_bytes(sparse)["per_btf"]
    return rank_budget(budget_bytes, cfg.n_light, cfg.n_view, cfg.height, cfg.width)


@dataclass
class Decomposition:
    """Principal components of a BTF's Y, U, V channels in the model space (log(x + eps), YUV), largest first.

    mean (3, LV) over texels; eigenvalues: per channel (R_c,), the squared error each component removes;
    basis (3, LV, R) orthonormal columns; coeffs (3, HW, R) = centred data @ basis; exact: False when
    computed by randomised subspace iteration (then only the leading R components are kept)."""

    mean: torch.Tensor
    eigenvalues: list[torch.Tensor]
    basis: torch.Tensor
    coeffs: torch.Tensor
    log_eps: float
    exact: bool
    total: torch.Tensor | None = None
    """(3,) squared norm of each channel's centred data (float64): total - kept eigenvalues = the squared
    error of a truncation."""

    def residual(self, ranks) -> torch.Tensor:
        """Mean squared error per element (model space) of keeping `ranks` components of Y, U, V."""
        kept = torch.stack([e[:r].double().sum() for e, r in zip(self.eigenvalues, ranks)])
        lv, hw = self.mean.shape[1], self.coeffs.shape[1]
        return ((self.total - kept).clamp(min=0).sum() / (3 * lv * hw)).float()


def decompose(btf: TabulatedBTF, log_eps: float | None = None, max_rank: int | None = None,
              exact_limit: int | None = None, oversample: int | None = None,
              power_iterations: int | None = None) -> Decomposition:
    """Principal components of `btf` (all of them, or the leading `max_rank`). Exact (eigendecomposition of
    the smaller Gram matrix, float64) unless both sides of the texel x angle matrix exceed `exact_limit` and
    `max_rank` is given: then randomised subspace iteration (`torch.svd_lowrank`, max_rank + `oversample`
    vectors, `power_iterations` passes, float64), whose leading eigenvalues match the exact ones within
    1e-4 relative (test). Defaults: log_eps from `neumat.methods.sparse_btf.pca.Config`, the others from the pca-btf
    recipe's options."""
    log_eps = Config().log_eps if log_eps is None else log_eps
    opts = typed_options("pca-btf", recipe_for("pca-btf").options)
    exact_limit = opts.exact_limit if exact_limit is None else exact_limit
    oversample = opts.oversample if oversample is None else oversample
    power_iterations = opts.power_iterations if power_iterations is None else power_iterations
    l, v, h, w, _ = btf.data.shape
    lv, hw = l * v, h * w
    if max_rank is not None and max_rank < 0:
        raise InputError(f"decompose: expected a non-negative max_rank, got {max_rank!r}")
    r_max = min(lv, hw) if max_rank is None else min(max_rank, lv, hw)
    exact = max_rank is None or min(lv, hw) <= exact_limit or r_max + oversample >= min(lv, hw)
    yuv = rgb_to_model_space(btf.data.float(), log_eps)                            # (L, V, H, W, 3)
    mean = torch.zeros(3, lv, device=btf.data.device)
    basis = torch.zeros(3, lv, max(r_max, 1), device=btf.data.device)
    coeffs = torch.zeros(3, hw, max(r_max, 1), device=btf.data.device)
    eigenvalues, total = [], torch.zeros(3, dtype=torch.float64, device=btf.data.device)
    for c in range(3):
        x = yuv[..., c].reshape(lv, hw).T.double()                                  # texels x angles
        mu = x.mean(0)
        xc = x - mu
        mean[c] = mu.float()
        total[c] = xc.square().sum()
        if exact:
            if lv <= hw:
                e, vecs = torch.linalg.eigh(xc.T @ xc)
                e, b = e.flip(0).clamp_min(0)[:r_max], vecs.flip(-1)[:, :r_max]
            else:                                 # texel Gram: basis = xc^T u / sqrt(e), for the kept components only
                e, u = torch.linalg.eigh(xc @ xc.T)
                e, u = e.flip(0).clamp_min(0)[:r_max], u.flip(-1)[:, :r_max]
                live = e > e[0] * 1e-12 if len(e) and e[0] > 0 else torch.zeros_like(e, dtype=torch.bool)
                b = torch.zeros(lv, len(e), dtype=xc.dtype, device=xc.device)
                b[:, live] = (xc.T @ u[:, live]) / e[live].sqrt()
        else:
            with torch.random.fork_rng(devices=[xc.device] if xc.is_cuda else []):
                torch.manual_seed(0)                      # the random test matrix: same components every run
                _, sv, b = torch.svd_lowrank(xc, q=r_max + oversample, niter=power_iterations)
            e, b = sv[:r_max] ** 2, b[:, :r_max]
        eigenvalues.append(e.float())
        basis[c, :, :b.shape[1]] = b.float()
        coeffs[c, :, :b.shape[1]] = (xc @ b).float()
    return Decomposition(mean, eigenvalues, basis, coeffs, log_eps, exact, total)


def best_ranks(spectra: list[torch.Tensor], total: int) -> tuple[int, int, int]:
    """The split of `total` principal components over Y, U, V with the least squared error, given the
    channels' eigenvalues (`Decomposition.eigenvalues`): the `total` largest eigenvalues of the three,
    counted per channel (every component costs the same, and each channel's eigenvalues fall)."""
    if total < 0:
        raise InputError(f"best_ranks: expected a non-negative component count, got {total!r}")
    channel = torch.cat([torch.full((len(e),), c, device=e.device) for c, e in enumerate(spectra)])
    order = torch.cat(spectra).argsort(descending=True, stable=True)[:total]
    return tuple(int((channel[order] == c).sum()) for c in range(3))
