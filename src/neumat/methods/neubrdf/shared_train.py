"""Training recipe and presets of NeuBRDF with codebooks shared across materials (Dou, Zheng et al. 2024, Sec. 3.3).

The joint fit trains the shared MLP and codebook and the t materials' index grids together with NeuBRDF's
optimiser, schedule, loss and staged grid training (`neumat.methods.neubrdf.train`); the source is a list of t BRDF
Materials, each batch split equally between them. Measurements: src/neumat/methods/neubrdf/NOTES.md.
"""
from __future__ import annotations

from dataclasses import dataclass, fields, replace

from neumat.core.config import bounded, config_to_dict
from neumat.fit.phase import FitContext, Phase
from neumat.fit.preset import Preset
from neumat.fit.recipe import Recipe
from neumat.methods.neubrdf.train import CPU_RECIPE as NEUBRDF_CPU_RECIPE
from neumat.methods.neubrdf.train import PRESETS as NEUBRDF_PRESETS
from neumat.methods.neubrdf.train import RECIPE as NEUBRDF_RECIPE
from neumat.methods.neubrdf.train import GridOptions, training_phases

@dataclass
class Options(GridOptions):
    """The clustering of `neumat.methods.neubrdf.shared_targets.cluster_materials` (paper: a convolutional autoencoder
    on tabulated reflectance, then k-means on its codes; sizes are ours) and NeuBRDF's staged grid training."""

    cluster_resolution: int = bounded(16, ge=2)
    """R^3 cells of the Rusinkiewicz table the autoencoder reads."""
    cluster_code_dim: int = bounded(8, ge=1)
    """Size of the autoencoder's code."""
    cluster_width: int = bounded(16, ge=1)
    """Channels of the autoencoder."""
    cluster_steps: int = bounded(500, ge=0)
    """Adam steps of the autoencoder."""
    cluster_lr: float = bounded(3e-3, gt=0)
    """Learning rate of the autoencoder."""


def _options(grid: dict) -> dict:
    return config_to_dict(Options(**{k: grid[k] for k in (f.name for f in fields(GridOptions))}))


RECIPE: Recipe = replace(NEUBRDF_RECIPE, options=_options(NEUBRDF_RECIPE.options))
#: NeuBRDF's CPU path for the joint fit: about 4-5 minutes for two materials at N_side 64 on one core
CPU_RECIPE: Recipe = replace(NEUBRDF_CPU_RECIPE, options=_options(NEUBRDF_CPU_RECIPE.options))

PRESETS = {
    "cpu": Preset("the paper's shared model along NeuBRDF's CPU path (coarse dense grid, dense N_side 64, one "
                  "k-means over all materials into the shared codebook, VQ)", recipe="cpu",
                  overrides={"model.features": "dense"}),
    "recommended": Preset(
        "NeuBRDF's recommended setting for a shared codebook: hd_warp direction inputs, the CPU path, MERL-density "
        "queries and the floored log loss on tables and analytic sources", recipe="cpu",
        overrides={"model.features": "dense", "model.direction_inputs": "hd_warp"},
        by_source={k: v for k, v in NEUBRDF_PRESETS["recommended"].by_source.items()}),
}


def phases(ctx: FitContext) -> list[Phase]:
    from neumat.methods.neubrdf.shared_targets import joint_source

    base = ctx.queries if isinstance(ctx.queries, str) else ctx.recipe.queries
    joint = joint_source(ctx.source, ctx.model.cfg.num_materials, base)
    draw = ctx.queries if ctx.queries is not None and not isinstance(ctx.queries, str) else "joint"
    return training_phases(replace(ctx, source=joint, queries=draw), ctx.recipe.steps)


def config_for_source(source, options: dict | None = None) -> dict:
    """num_materials: the number of source materials (a list or tuple)."""
    return {"num_materials": len(source)} if isinstance(source, (list, tuple)) else {}
