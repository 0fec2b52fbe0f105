"""Training recipe and presets of NeuBRDF (Dou, Zheng et al., CVPR 2024).

RECIPE is the paper's end-to-end VQ training (its optimiser settings are in a supplement we do not have; ours
are argued in src/neumat/methods/neubrdf/NOTES.md); CPU_RECIPE trains the paper's model coarse to fine on dense
features, then quantises them into the codebook (about 4-8 minutes on one core). `Options` are the typed recipe options;
`PRESETS` the named settings, "recommended" the best we measured (src/neumat/methods/neubrdf/NOTES.md, with evidence).
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Literal

from neumat.core.config import bounded, config_to_dict
from neumat.core.errors import InputError
from neumat.core.material import describe_source
from neumat.methods.neubrdf.feature_sensitivity import feature_sensitivity
from neumat.fit.phase import FitContext, Phase, online_phase, query_draw
from neumat.fit.preset import Preset
from neumat.fit.recipe import Recipe


@dataclass
class GridOptions:
    """The staged training of a feature grid, shared by NeuBRDF and SharedNeuBRDF
    (src/neumat/methods/neubrdf/NOTES.md)."""

    coarse_fraction: float = bounded(0.0, ge=0, lt=1)
    """Fraction of the steps trained first on a coarse dense grid, then regridded to the model's N_side (0: off)."""
    coarse_nside: int = bounded(0, ge=0)
    """N_side of the coarse grid, a power of two below the model's; 0: a quarter of it."""
    fine_lr_scale: float = bounded(0.25, gt=0, le=1)
    """Learning-rate factor of the phases after the coarse one (they refine a grid that already fits)."""
    dense_warmup: float = bounded(0.0, ge=0, lt=1)
    """Fraction of the steps on dense features before k-means quantises them into the codebook (0: end-to-end VQ)."""
    vq_candidates: int = bounded(0, ge=0)
    """After a dense warm-up, codewords kept per slot for the VQ phase (0, or more than 2^index_bits: all)."""


@dataclass
class Options(GridOptions):
    """NeuBRDF's recipe options (src/neumat/methods/neubrdf/NOTES.md gives each one's reason and measurements)."""

    direction_features: float = bounded(0.0, ge=0)
    """Scale of a direction-coded start of the first 3 dense feature channels (0: random start)."""
    prune: bool = False
    """Prune the grid to the measured directions before training (paper Sec. 3.2.1); needs replay queries."""
    measured_azimuths: int = bounded(64, ge=1)
    """With replay queries on an isotropic RGL file: incident azimuths its measured one is rotated to."""
    measured_reciprocal: bool = False
    """With replay queries: each measured (wi, wo) also trained as (wo, wi) (`MeasuredSamples.reciprocal`)."""
    runtime_fraction: float = bounded(0.0, ge=0, lt=1)
    """Last fraction of the steps trained in the 1/4-weight runtime form against pixel-pair averages (0: off)."""
    runtime_samples: int = bounded(32, ge=1)
    """Points per query of the pixel-pair averages of the runtime phase."""
    kmeans_weights: Literal["uniform", "sensitivity"] = "uniform"
    """Weights of the k-means ending a dense warm-up: plain, or by the loss's sensitivity to each slot's features."""
    sensitivity_batches: int = bounded(80, ge=1)
    """Batches of the sensitivity estimate of kmeans_weights=sensitivity."""


RECIPE = Recipe(steps=20000, batch_size=2 ** 14, lr=1e-2, betas=(0.9, 0.999), eps=1e-8, lr_decay=0.5,
                lr_decay_every=5000, ema=0.01, loss="log_cos", queries="cosine", seed=0, grad_clip=0.0,
                log_every=100, schedule="step", checkpoint_every=2000, options=config_to_dict(Options()))

#: the paper's model on one CPU core: coarse N_side 16, dense N_side 64, then the codebook
#: (src/neumat/methods/neubrdf/NOTES.md)
CPU_RECIPE = Recipe(steps=5000, batch_size=2 ** 13, lr=1e-2, betas=(0.9, 0.999), eps=1e-8, lr_decay=0.5,
                    lr_decay_every=5000, ema=0.01, loss="log_cos", queries="cosine", seed=0, grad_clip=0.0,
                    log_every=100, schedule="halves", checkpoint_every=500,
                    options=config_to_dict(Options(coarse_fraction=0.4, dense_warmup=0.7, vq_candidates=8)))

#: a dense grid (19x the codebook's bytes) with a direction-coded start and a runtime-form phase: the lowest errors
#: measured, not the paper's model (src/neumat/methods/neubrdf/NOTES.md)
DENSE_RECIPE = replace(CPU_RECIPE, loss="log_cos_eps", queries="cosine_merl",
                       options=config_to_dict(Options(coarse_fraction=0.4, direction_features=10.0,
                                                              runtime_fraction=0.2)))
NAMED_RECIPES = {"dense": DENSE_RECIPE}
#: the query samplers that draw a source's measured samples (`neumat.fit.query_samplers`)
REPLAY_QUERIES = ("replay", "replay_cells")

#: the recommended setting's queries and loss; on RGL measured files they are left at the paper's (see PRESETS)
_DENSE_SAMPLING = {"recipe.queries": "cosine_merl", "recipe.loss": "log_cos_eps"}

PRESETS = {
    "cpu": Preset("the paper's model (codebook, N_side 64) along the fastest CPU path we measured: coarse dense "
                  "grid, dense N_side 64, k-means into the codebook, VQ", recipe="cpu",
                  overrides={"model.features": "dense"}),
    "dense": Preset("a dense grid with a direction-coded start and a runtime-form phase: the lowest errors, 19x the "
                    "paper's bytes", recipe="dense", overrides={"model.features": "dense"}),
    "recommended": Preset(
        "the paper's model and byte budget plus NBRDF's half/difference vectors as MLP inputs (hd_warp), trained "
        "along the CPU path; on tables and analytic sources with MERL-density queries and the floored log loss",
        recipe="cpu", overrides={"model.features": "dense", "model.direction_inputs": "hd_warp"},
        by_source={"merl": _DENSE_SAMPLING, "analytic": _DENSE_SAMPLING, "model": _DENSE_SAMPLING}),
}


def phases(ctx: FitContext) -> list[Phase]:
    """One online phase, or the stages the options ask for, in this order (each with the learning-rate schedule
    over its own steps; all on the measured samples of the source and with a pruned model under options
    queries "replay" or "replay_cells" / prune, see `_measured`):

    "coarse" (option coarse_fraction = c > 0): round(c steps) steps on a dense grid at coarse_nside (the model
    is regridded to it now); at its end `NeuBRDF.regrid` back to the model's N_side.
    "dense" (option dense_warmup = f > 0): the dense steps left up to round(f steps); at their end
    `quantize_from_dense` (with vq_candidates).
    "vq" (f > 0) or "fine" (c > 0, no warm-up: a dense model): the remaining steps.

    "runtime" (option runtime_fraction = r > 0): the last round(r steps) steps, in the runtime form against
    pixel-pair averages (see the option).

    Checkpoints hold the state of whichever grid the fit is on; a freshly built model loads any of them
    (`neumat.methods.neubrdf.model.regridded_state`, `quantized_state`), so resuming is exact in every phase."""
    ctx = _measured(ctx)
    runtime_steps = _runtime_steps(ctx)
    nside = ctx.model.cfg.nside  # the model's own; a coarse phase regrids it now
    built = training_phases(ctx, ctx.recipe.steps - runtime_steps)
    if runtime_steps:
        built.append(_runtime_phase(ctx, runtime_steps, nside))
    return built


def training_phases(ctx: FitContext, steps: int) -> list[Phase]:
    """The phases before the runtime one: coarse, dense / fine, vq (see `phases`), `steps` in all. Also those of
    SharedNeuBRDF (`neumat.methods.neubrdf.shared_train`), whose model offers the same `regrid` and
    `quantize_from_dense`."""
    o, model = ctx.opts, ctx.model
    frac, coarse, candidates = o.dense_warmup, o.coarse_fraction, o.vq_candidates
    weighting = getattr(o, "kmeans_weights", "uniform")
    directions = getattr(o, "direction_features", 0.0)
    if frac and coarse > frac:
        raise InputError(f"neubrdf recipe option coarse_fraction={coarse}: the coarse steps are part of the dense "
                         f"warm-up, so at most dense_warmup={frac}")
    candidates = min(candidates, 2 ** model.cfg.index_bits)  # more than the codebook holds: all of them
    if weighting != "uniform" and frac == 0:
        raise InputError(f"neubrdf recipe option kmeans_weights={weighting!r}: needs dense_warmup > 0 (it weighs the "
                         "k-means that ends the warm-up)")
    if candidates and frac == 0:
        raise InputError("neubrdf recipe option vq_candidates: needs dense_warmup > 0 (the candidates are "
                         "each slot's nearest codewords after the warm-up's k-means)")
    if coarse:
        _coarse_nside(o.coarse_nside, model.cfg.nside)
    if frac == 0 and coarse == 0 and not directions:
        return [online_phase(ctx, steps=steps)]
    features = getattr(getattr(model, "cfg", None), "features", None)
    if features != "dense":
        why = (f"dense_warmup={frac}: needs a model built with features='dense' (the warm-up's features are "
               "quantised into the codebook afterwards)" if frac else
               f"coarse_fraction={coarse}: needs a model built with features='dense' (or a dense_warmup, to end "
               "with the codebook)" if coarse else
               f"direction_features={directions}: needs a model built with features='dense'")
        raise InputError(f"neubrdf recipe option {why}, got features={features!r} (set model.features=dense)")
    fine_nside = model.cfg.nside
    coarse_steps = min(max(int(round(coarse * steps)), 1), steps) if coarse else 0
    dense_end = min(max(int(round(frac * steps)), 1), steps) if frac else steps
    if coarse:
        if getattr(o, "prune", False):
            raise InputError(f"neubrdf recipe options coarse_fraction={coarse} and prune: a pruned grid cannot be "
                             "regridded; use one or the other (--preset paper trains without a coarse grid)")
        model.regrid(_coarse_nside(o.coarse_nside, fine_nside))
    if directions:
        model.init_direction_features(directions)  # a resumed fit loads its checkpoint over it
    if frac == 0 and coarse == 0:
        return [online_phase(ctx, steps=steps)]

    def leave_coarse():
        model.regrid(fine_nside)
        if frac and dense_end == coarse_steps:  # no dense steps at the model's N_side: quantise right away
            quantize()

    def quantize():
        weights = feature_sensitivity(ctx, o.sensitivity_batches, ctx.recipe.seed + 2) \
            if weighting == "sensitivity" else None
        model.quantize_from_dense(candidates=candidates, weights=weights)

    built, later = [], replace(ctx, resuming=True)  # the first phase initialises the output scale once
    if coarse_steps:
        built.append(online_phase(ctx, "coarse", coarse_steps))
        built[-1].after = leave_coarse
    if dense_end > coarse_steps:
        built.append(online_phase(later if built else ctx, "dense" if frac else "fine", dense_end - coarse_steps))
        if frac:
            built[-1].after = quantize
    if frac:
        built.append(online_phase(later, "vq", steps - dense_end))
    for phase in built[1:]:
        phase.params = lambda: [p for p in model.parameters() if p.requires_grad]
        if coarse:
            phase.optimizer = _scaled(phase.optimizer, o.fine_lr_scale)
    return [phase for phase in built if phase.steps > 0]


def _runtime_phase(ctx: FitContext, steps: int, nside: int) -> Phase:
    """`steps` steps of the model (N_side `nside`) in its 1/4-weight runtime form against the source's pixel-pair
    averages (option runtime_samples points per query, drawn from the fit's generator), at fine_lr_scale times
    the rate."""
    from neumat.methods.neubrdf.pixel_pair_targets import PixelPairAverage

    model = ctx.model
    targets = PixelPairAverage(ctx.source, nside, ctx.opts.runtime_samples, ctx.generator)
    phase = online_phase(replace(ctx, source=targets, queries=query_draw(ctx), resuming=True), "runtime", steps)

    def start() -> None:
        model.cfg = replace(model.cfg, interpolation="uniform")

    phase.start = start
    phase.params = lambda: [p for p in model.parameters() if p.requires_grad]
    phase.optimizer = _scaled(phase.optimizer, ctx.opts.fine_lr_scale)
    return phase


def _runtime_steps(ctx: FitContext) -> int:
    """Steps of the runtime phase (0: none); InputError for a fraction out of range or a fit it cannot serve."""
    frac = ctx.opts.runtime_fraction
    if frac == 0:
        return 0
    queries = ctx.queries if ctx.queries is not None else ctx.recipe.queries
    if queries in REPLAY_QUERIES:
        raise InputError(f"neubrdf recipe option runtime_fraction={frac}: needs a source it can evaluate anywhere "
                         f"(its targets average the source over pixel pairs); queries={queries} fits measured "
                         "samples only")
    form = getattr(getattr(ctx.model, "cfg", None), "runtime_interpolation", None)
    if form != "uniform":
        raise InputError(f"neubrdf recipe option runtime_fraction={frac}: the model's runtime_interpolation is "
                         f"{form!r}, whose runtime form is the training form already; it serves 'uniform' only")
    steps = ctx.recipe.steps
    runtime = min(max(int(round(frac * steps)), 1), steps)
    if runtime == steps:
        raise InputError(f"neubrdf recipe option runtime_fraction={frac}: leaves none of the {steps} steps for "
                         "training before it")
    return runtime


def _scaled(make, factor: float):
    """An optimiser factory like `make` whose param groups learn at `factor` times their rate ("lr_scale")."""
    def scaled(params, lr, betas, eps):
        opt = make(params, lr, betas, eps)
        for group in opt.param_groups:
            group["lr_scale"] = group.get("lr_scale", 1.0) * factor
        return opt
    return scaled


def _coarse_nside(n: int, fine: int) -> int:
    """The coarse grid's N_side: option coarse_nside, or 0 for a quarter of the model's `fine` N_side (at least 1)."""
    nside = n or max(fine // 4, 1)
    if nside & (nside - 1) or nside >= fine:
        raise InputError(f"neubrdf recipe option coarse_nside: expected a power of two below the model's N_side "
                         f"{fine} (0: a quarter of it), got {n}")
    return nside


def _measured(ctx: FitContext) -> FitContext:
    """The fit's context for sparse measurements: with replay queries (`REPLAY_QUERIES`) the source must hold
    measurement samples (a `MeasuredSamples`, or an RGL file whose measurement directions `rgl_samples` gives, then
    the source of the fit), with their reciprocal pairs under option measured_reciprocal; with option prune the model
    is pruned to their directions first (`NeuBRDF.prune`, deterministic, so a resumed fit prunes the same way).
    InputError for prune without replay queries and for replay on a source without measurement samples."""
    from neumat.reflectance.measured import RglMaterial
    from neumat.fit.measured_samples import MeasuredSamples, rgl_samples

    prune = ctx.opts.prune
    queries = ctx.queries if ctx.queries is not None else ctx.recipe.queries
    if queries not in REPLAY_QUERIES:
        if prune:
            raise InputError(f"neubrdf recipe option prune=true: needs queries=replay or replay_cells (the model is "
                             f"pruned to the measured directions and must train on them), got queries={queries!r}")
        return ctx
    source = ctx.source
    if isinstance(source, RglMaterial):
        source = rgl_samples(source, ctx.opts.measured_azimuths)
    elif not isinstance(source, MeasuredSamples):
        name = describe_source(source)
        raise InputError(f"neubrdf with queries={queries}{' and prune=true' if prune else ''}: the source "
                         f"{name!r} holds no measurement samples; give an RGL *_rgb.bsdf file or "
                         f"neumat.fit.measured_samples.MeasuredSamples")
    if ctx.opts.measured_reciprocal:
        source = source.reciprocal()
    if prune:
        ctx.model.prune(source.wi.to(ctx.device), source.wo.to(ctx.device))
    return replace(ctx, source=source)
