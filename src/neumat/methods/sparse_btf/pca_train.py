"""Training recipe of the PCA-BTF baseline (SparseBTF paper, Table 5): one solver phase of one step, the
truncated PCA of the source BTF (`neumat.methods.sparse_btf.pca_solve.decompose`, then the model keeps its cfg.ranks
leading components; a model built without ranks, the default, keeps the most that fit the option budget_bytes, by
default SparseBTF's per-BTF bytes, split over Y, U, V by least error). `fit(PCABTF.for_btf(btf), btf)`; the source
is one tabulated BTF (`neumat.io.btf.read_btf`). The step logs "mse", the model-space mean squared error of the
truncation.

`Options` are those of the solve (`decompose`). steps, batch_size, lr and the schedule are unused.

CPU_RECIPE: RECIPE itself: its one step is the PCA of the BTF, no optimiser budget to size; its time follows the
BTF's size.
"""
from __future__ import annotations

from dataclasses import dataclass

from neumat.core.config import bounded, config_to_dict
from neumat.core.errors import InputError
from neumat.methods.sparse_btf.btf_size import btf_table_size
from neumat.fit.phase import FitContext, Phase
from neumat.fit.recipe import Recipe



@dataclass
class Options:
    """Options of the PCA solve (`neumat.methods.sparse_btf.pca_solve.decompose`)."""

    exact_limit: int = bounded(4096, ge=0)
    """Exact eigendecomposition of the smaller Gram matrix unless both sides of the texel x angle matrix exceed this."""
    oversample: int = bounded(16, ge=0)
    """Extra vectors of the randomised subspace iteration used otherwise."""
    power_iterations: int = bounded(6, ge=0)
    """Passes of that randomised subspace iteration."""
    budget_bytes: int = bounded(0, ge=0)
    """Storage of a model built without ranks (the default): the most components that fit in it, split over
    Y, U, V by least error; 0: SparseBTF's per-BTF bytes for the same BTF (the paper's comparison at equal
    storage; `neumat.methods.sparse_btf.pca_solve.budget_components`)."""


RECIPE = Recipe(steps=1, batch_size=1, lr=1.0, log_every=1, options=config_to_dict(Options()))

#: RECIPE itself (module docstring)
CPU_RECIPE = RECIPE


def config_for_source(btf, options: dict | None = None) -> dict:
    """The model's size from the BTF (direction counts, texels)."""
    return btf_table_size(btf, "pca-btf")


def phases(ctx: FitContext) -> list[Phase]:
    from neumat.methods.sparse_btf.pca import PCABTF
    from neumat.reflectance.btf import TabulatedBTF
    from neumat.methods.sparse_btf.pca_solve import solve_into

    model, btf = ctx.model, ctx.source
    if not isinstance(model, PCABTF):
        raise InputError(f"pca-btf recipe: expected a PCABTF model, got {type(model).__name__}")
    model.check_source(btf)

    def solve(step: int) -> dict:
        data = btf.data.to(ctx.device)
        table = TabulatedBTF(data, btf.light_dirs, btf.view_dirs, btf.neighbours, label=btf.label)
        o = ctx.opts
        dec = solve_into(model, table, o.budget_bytes, exact_limit=o.exact_limit, oversample=o.oversample,
                         power_iterations=o.power_iterations)
        return {"mse": dec.residual(model.cfg.ranks)}

    return [Phase("solve", 1, solve)]
