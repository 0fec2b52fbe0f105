"""Training recipe of NeuBRDF with codebooks shared across materials (Dou, Zheng et al. 2024, Sec. 3.3).

The joint fit trains the shared MLP, the shared codebook and the t materials' index grids together, with
NeuBRDF's optimiser, schedule, loss and batch (`neumat.fit.recipes.neubrdf`, where each value's reason is
given): `fit(SharedNeuBRDF(num_materials=t, ...), [source_0, ..., source_t-1])`. The source is a LIST (or
tuple) of t plain BRDF Materials; the phase wraps it in a `neumat.fit.shared_neubrdf.JointSource` and draws
every batch with the "joint" sampler, an equal share per material drawn by the recipe's `queries` sampler
(the base sampler of each material, "cosine" as NeuBRDF's).

Options: the clustering of `neumat.fit.shared_neubrdf.cluster_materials` (paper: a convolutional autoencoder
on tabulated reflectance, then k-means on its codes; sizes are ours): "cluster_resolution" (16: R^3 cells of
the Rusinkiewicz table), "cluster_code_dim" (8), "cluster_width" (16 channels), "cluster_steps" (500 Adam
steps of the autoencoder), "cluster_lr" (3e-3).

CPU_RECIPE: NeuBRDF's recipe shortened to 1500 steps of 2^13 (its four halvings every 375 steps), end-to-end
VQ with these options (the joint fit has no coarse or dense phases, so every step carries the full 2^b-way
straight-through estimator over each material's touched slots): measured 1747-1779 s for two materials at N_side 64
on one core beside other jobs (benchmarks/results/neubrdf_table3_hd_warp.md, section 6), about 30 minutes:
above the 15 minutes every CPU recipe is held to and the 10 that CPU_MINUTES still states (open; it was sized
from a NeuBRDF step, which the candidate-restricted VQ of NeuBRDF's CPU recipe makes much cheaper).
"""
from __future__ import annotations

from dataclasses import replace

from ..phase import FitContext, Phase, online_phase
from ..recipe import Recipe
from .neubrdf import RECIPE as NEUBRDF_RECIPE

RECIPE: Recipe = replace(NEUBRDF_RECIPE, options={"cluster_resolution": 16, "cluster_code_dim": 8,
                                                  "cluster_width": 16, "cluster_steps": 500, "cluster_lr": 3e-3})
#: NeuBRDF's recipe shortened for a CPU, with the same options (module docstring)
CPU_RECIPE: Recipe = replace(RECIPE, steps=1500, batch_size=2 ** 13, lr_decay_every=375, log_every=50,
                             checkpoint_every=250, options=dict(RECIPE.options))
CPU_MINUTES = 10


def phases(ctx: FitContext) -> list[Phase]:
    from ..shared_neubrdf import joint_source

    base = ctx.queries if isinstance(ctx.queries, str) else ctx.recipe.queries
    joint = joint_source(ctx.source, ctx.model.cfg.num_materials, base)
    draw = ctx.queries if ctx.queries is not None and not isinstance(ctx.queries, str) else "joint"
    return [online_phase(replace(ctx, source=joint, queries=draw))]


def config_for_source(source, options: dict | None = None) -> dict:
    """Config defaults from the source: num_materials = the number of source materials (a list / tuple)."""
    return {"num_materials": len(source)} if isinstance(source, (list, tuple)) else {}
