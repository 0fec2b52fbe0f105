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

Options of NeuBRDF's recipe that the joint fit takes, with NeuBRDF's meanings (`neumat.fit.recipes.neubrdf`):
"coarse_fraction", "coarse_nside", "fine_lr_scale", "dense_warmup", "vq_candidates"; all off in RECIPE (the paper's
end-to-end VQ). With dense_warmup the model is built with dense features per material and slot, and the k-means
at the warm-up's end clusters the slots of all t materials into the one shared codebook
(`SharedNeuBRDF.quantize_from_dense`).

CPU_RECIPE: NeuBRDF's CPU recipe (5000 steps of 2^13, coarse N_side 16 up to 40 %, dense N_side 64 up to 70 %,
then the shared codebook with 8 candidate codewords per slot, "halves" schedule), every batch split equally
between the materials. Two MERL-like materials at N_side 64 with hd_warp inputs: 249 - 268 s on one core beside
another fit, image MAE at 0.8 - 1.3x the own fits', ahead of NBRDF on all four; the paper's end-to-end VQ
shortened to 1500 steps took 1747 - 1779 s at 2 - 2.7x the own fits' error
(benchmarks/studies/neubrdf/results/neubrdf_table3_hd_warp.md, section 6). More materials add k-means time (about 15 s each).
"""
from __future__ import annotations

from dataclasses import replace

from ..phase import FitContext, Phase
from ..recipe import Recipe
from .neubrdf import CPU_RECIPE as NEUBRDF_CPU_RECIPE
from .neubrdf import OPTIONS as NEUBRDF_OPTIONS
from .neubrdf import RECIPE as NEUBRDF_RECIPE
from .neubrdf import warmup_fraction, training_phases

#: the clustering's options, then the NeuBRDF options the joint fit takes (module docstring)
OPTIONS = {"cluster_resolution": 16, "cluster_code_dim": 8, "cluster_width": 16, "cluster_steps": 500,
           "cluster_lr": 3e-3, **{k: NEUBRDF_OPTIONS[k] for k in ("coarse_fraction", "coarse_nside", "fine_lr_scale",
                                                                   "dense_warmup", "vq_candidates")}}
RECIPE: Recipe = replace(NEUBRDF_RECIPE, options=dict(OPTIONS))
#: NeuBRDF's CPU path for the joint fit (module docstring)
CPU_RECIPE: Recipe = replace(NEUBRDF_CPU_RECIPE, options={
    **OPTIONS, **{k: NEUBRDF_CPU_RECIPE.options[k] for k in ("coarse_fraction", "dense_warmup", "vq_candidates")}})
CPU_MINUTES = 6


def phases(ctx: FitContext) -> list[Phase]:
    from ..shared_neubrdf import joint_source

    base = ctx.queries if isinstance(ctx.queries, str) else ctx.recipe.queries
    joint = joint_source(ctx.source, ctx.model.cfg.num_materials, base)
    draw = ctx.queries if ctx.queries is not None and not isinstance(ctx.queries, str) else "joint"
    return training_phases(replace(ctx, source=joint, queries=draw), ctx.recipe.steps)


def config_for_source(source, options: dict | None = None) -> dict:
    """Config defaults from the source and the options: num_materials = the number of source materials (a list /
    tuple); dense features for a dense warm-up."""
    derived = {"num_materials": len(source)} if isinstance(source, (list, tuple)) else {}
    return {**derived, "features": "dense"} if warmup_fraction(options or {}) > 0 else derived
