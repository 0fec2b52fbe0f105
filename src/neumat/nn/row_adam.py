"""Adam that also takes sparse row gradients, for per-vertex parameters of which a batch touches few rows."""
from __future__ import annotations

import math

import torch

from neumat.nn.codebook import VQFeatures, scratch


def _coalesced(g: torch.Tensor) -> torch.Tensor:
    """`g.coalesce()`, without the sort and copy when g is row-sparse with strictly increasing row indices
    (as the gradients of `VQFeatures`, which autograd's accumulation marks uncoalesced): those are marked
    coalesced in place."""
    if not g.is_coalesced() and g.sparse_dim() == 1:
        rows = g._indices()[0]
        if rows.numel() < 2 or bool((rows[1:] > rows[:-1]).all()):
            return g._coalesced_(True)
    return g.coalesce()


class RowAdam(torch.optim.Optimizer):
    """Adam (torch.optim.Adam's update, no weight decay / amsgrad) that also takes sparse gradients: a
    parameter with a sparse row gradient (e.g. `VQFeatures.logits` with `sparse_grad`) is updated lazily,
    only on the rows present in the gradient, whose moments alone advance (as torch.optim.SparseAdam). The
    gathered rows live in reused scratch memory (see `neumat.nn.codebook.scratch`)."""

    def __init__(self, params, lr: float = 1e-3, betas: tuple[float, float] = (0.9, 0.999),
                 eps: float = 1e-8) -> None:
        super().__init__(params, dict(lr=lr, betas=tuple(betas), eps=eps))

    @torch.no_grad()
    def step(self, closure=None):
        loss = None
        if closure is not None:
            with torch.enable_grad():
                loss = closure()
        for group in self.param_groups:
            lr, (b1, b2), eps = group["lr"], group["betas"], group["eps"]
            for p in group["params"]:
                if p.grad is None:
                    continue
                state = self.state[p]
                if not state:
                    state["step"] = torch.zeros((), dtype=torch.float32)
                    state["exp_avg"] = torch.zeros_like(p, memory_format=torch.preserve_format)
                    state["exp_avg_sq"] = torch.zeros_like(p, memory_format=torch.preserve_format)
                state["step"] += 1
                t = state["step"].item()
                step_size, bc2_sqrt = lr / (1 - b1 ** t), math.sqrt(1 - b2 ** t)
                m, v = state["exp_avg"], state["exp_avg_sq"]
                if p.grad.is_sparse:
                    g = _coalesced(p.grad)
                    rows, vals = g.indices()[0], g.values()
                    work = self.__dict__.setdefault("_scratch", {})
                    m_r = torch.index_select(m, 0, rows, out=scratch(work, "m", rows.shape[0], vals[0].numel(), m)
                                             .view_as(vals)).lerp_(vals, 1 - b1)
                    v_r = torch.index_select(v, 0, rows, out=scratch(work, "v", rows.shape[0], vals[0].numel(), v)
                                             .view_as(vals)).mul_(b2).addcmul_(vals, vals, value=1 - b2)
                    m.index_copy_(0, rows, m_r)
                    v.index_copy_(0, rows, v_r)
                    # m / (sqrt(v) / c + eps) = c m / (sqrt(v) + c eps), c = bc2_sqrt: one pass fewer
                    upd = m_r.div_(v_r.sqrt_().add_(bc2_sqrt * eps))
                    p.index_add_(0, rows, upd, alpha=-step_size * bc2_sqrt)
                else:
                    g = p.grad
                    m.lerp_(g, 1 - b1)
                    v.mul_(b2).addcmul_(g, g, value=1 - b2)
                    p.addcdiv_(m, v.sqrt().div_(bc2_sqrt).add_(eps), value=-step_size)
        return loss


def grid_optimizer(module: torch.nn.Module, grid, lr: float, betas: tuple[float, float] = (0.9, 0.999),
                   eps: float = 1e-8, index_lr_scale: float = 1.0) -> RowAdam:
    """The optimiser of a model whose feature grid `grid` may be a training `VQFeatures`: RowAdam on every
    trainable parameter of `module`, with the grid's index logits switched to sparse row gradients (updated
    lazily, only on the vertices of each batch, instead of a dense step over all V x 2^b logits) at
    `index_lr_scale` times the learning rate; plain Adam's update for any other grid."""
    params = [p for p in module.parameters() if p.requires_grad]
    if not isinstance(grid, VQFeatures) or grid.frozen or not grid.logits.requires_grad:
        return RowAdam(params, lr=lr, betas=betas, eps=eps)
    grid.sparse_grad = True
    rest = [p for p in params if p is not grid.logits]
    return RowAdam([{"params": rest}, {"params": [grid.logits], "lr_scale": index_lr_scale}],
                   lr=lr, betas=betas, eps=eps)
