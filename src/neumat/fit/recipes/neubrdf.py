"""Training recipe of NeuBRDF (Dou, Zheng et al., CVPR 2024).

What the paper fixes: PyTorch, the primitives (codebook), indices and MLP trained jointly end to end
following VQ-AD (Takikawa et al. 2022); the model defaults (N_side 64, k 16, b 9, MLP 2 x 64) live in
`neumat.models.neubrdf.Config`. Its optimiser settings, schedule and loss are in the supplement, which we
do not have; the values below are therefore ours, each with its reason:

- loss "log_cos": |log(1 + f_hat cos_i) - log(1 + f cos_i)| (L1), the loss of NBRDF (Sztrajman et al.
  2021), which NeuBRDF compares against on MERL with NBRDF's protocol: errors weighted by the cosine
  and compressed in log space at bright specular peaks, roughly as they show in rendered images.
- queries "cosine": online targets at cosine-weighted (wi, wo), i.e. weighted as they matter in rendering;
  use queries="rusinkiewicz" for a MERL-like density, "replay" for sparse measurements (then call
  `model.prune(samples.wi, samples.wo)` first, paper Sec. 3.2.1).
- Adam, lr 1e-2, halved every 5000 of 20000 steps, batch 2^14: feature-grid models train with larger
  learning rates than plain MLPs (Instant-NGP uses 1e-2). Measured on a Lambert + Blinn-Phong lobe,
  N_side 16, b 9, 600 steps of 4096 queries (lr halved every 200): relative L2 error 0.25 / 0.18 / 0.15
  at lr 3e-3 / 1e-2 / 3e-2; short fits favour the largest rate, the long default run decays from 1e-2.
  20000 x 2^14 = 3.3e8 target evaluations, as many as 220 passes over a MERL table (1.46e6 cells).
- EMA 0.01 (a window of about 100 steps) averages the noise of the last steps; on the lobe above at
  N_side 8 (300 steps, lr 3e-2, EMA 0.05) it lowers the relative error from 0.29 to 0.24 (vq) and from
  0.089 to 0.074 (dense).

Positivity and dynamic range are handled by the model, not the recipe: the MLP predicts log f and the
model returns exp(.) (positive, smooth gradients in log space), 0 below the horizon.

Collapse on dark measured materials, and the two model defaults that prevent it. With a ReLU MLP and the
default initialisation (outputs near exp(0) = 1), the fit of RGL cc_ibiza_sunset (a dark paint under a
clear coat: per-channel medians 0.009 / 0.0035 / 0.001, 12 % of the measured values negative) died within
15 steps: every ReLU unit of the second hidden layer stopped firing and the output fell to ~1e-7, where the
log_cos gradient (prop. to f) vanishes; the loss stayed at the all-zero value 0.034. Not the cause: the
learning rate (3e-3 collapsed too), negative targets (clamping them changed nothing), the VQ codebook
(dense collapsed too), a learning-rate warm-up (100 or 300 steps). What fixes it (N_side 16, 300 steps of
2^14 replaying 2^18 measured samples, log_cos error on held-out queries; all-zero output 0.0320):
  - ReLU as before: 0.0320 (collapsed); ReLU + start at the median: 0.0207 on cc_ibiza_sunset, but one
    channel of cc_iris_purple_gem still collapsed and paper_white stalled at a constant (0.0099);
  - SiLU + start at the median (`NeuBRDF.init_from_targets`, called by the trainer with the targets of
    one batch): 0.0180 on cc_ibiza_sunset, 0.0180 on cc_iris_purple_gem (all-zero 0.0249), 0.0040 on
    paper_white (0.0086 with ReLU at the same budget); leaky ReLU + start at the median: 0.0202 on
    cc_ibiza_sunset, no collapse;
  - NBRDF's output max(e^x - 1, 0) instead of exp, which keeps the log_cos gradient from vanishing: its
    clamp killed channels instead (0.0310).
The defaults are leaky ReLU (`Config.activation`) and the start at the median: at 1000 steps (index
logits at 10x the rate, `NeuBRDF.index_lr_scale`) leaky ReLU and SiLU fit equally well (vch_golden_yellow
0.0095 / 0.0102, cc_iris_purple_gem 0.0091 / 0.0087), and leaky ReLU evaluates ~30 % faster (runtime mode,
one thread: 2.4-2.8e6 vs 1.8-1.9e6 evaluations per CPU second).

CPU budget (benchmarks/studies/neubrdf/neubrdf_speed.py; one thread, batch 8192, k 16, b 9, MLP 2 x 64, CPU seconds per
step on a shared, loaded 2-core machine): "vq" 0.054 / 0.12 / 0.43 s at N_side 16 / 32 / 64 (0.43 s was
1.07 s before the unique-slot straight-through and the lazy row-wise Adam of `NeuBRDF.optimizer`, which
the trainer must call to get these numbers),
"dense" 0.03 - 0.045 s, "lowbit" 0.05 - 0.07 s. The full recipe (20000 steps of 2^14) is meant for a GPU
(about 7 hours on one CPU core at N_side 64). On a busy machine use one torch thread (two threads on two
loaded cores ran 3 - 10x slower than one).

CPU_RECIPE, what `neumat fit` runs on a CPU unless told otherwise: the paper's model (N_side 64, k 16, b 9,
MLP 2 x 64) along the fastest path to its quality that we measured (benchmarks/studies/neubrdf/results/neubrdf_paper_size.md,
equal wall time, one thread): 5000 steps of 2^13, the first 40 % on a dense N_side 16 grid (coarse_fraction),
then dense at N_side 64 up to 70 % (dense_warmup), then the codebook model with 8 candidate codewords per slot
(vq_candidates), the learning rate halved at 1/2 and 3/4 of each phase ("halves"), EMA 0.01. At equal time
(4-5 minutes) the paper's end-to-end VQ reached a held-out log error of 0.0129 on MERL-like gold-paint and
0.0331 on RGL vch_golden_yellow (570 - 620 steps), this path 0.0022 and 0.0096 (2850 - 4760 steps). About 8
minutes on one core (0.07 / 0.08 / 0.11 s per step of the three phases on a loaded machine, k-means 15 s).
With the model option `direction_inputs="hd"` (`neumat.models.neubrdf.Config`: NBRDF's h and d as 6 more MLP
inputs, not the paper's model) the same recipe ends on the 25 MERL-like tables at a mean Table 3 image MAE of
0.0012 and SSIM 0.9978, against 0.0112 / 0.935 without, and with queries="cosine_merl", loss="log_cos_eps" at
0.0010 / 0.9983, lower than NBRDF on 24 of 25 (benchmarks/studies/neubrdf/results/neubrdf_table3_hd.md). With the half vector warped
to MERL's sqrt(theta_h) coordinate (`direction_inputs="hd_warp"`) and those queries and loss: 0.0006 / 0.9995, lower
than NBRDF and GGX on all 25 (benchmarks/studies/neubrdf/results/neubrdf_table3_hd_warp.md); what we recommend, though not the
paper's model.
"""
from __future__ import annotations

from dataclasses import replace

from ...core.errors import InputError
from ..feature_sensitivity import feature_sensitivity
from ..phase import FitContext, Phase, online_phase, query_draw
from ..recipe import Recipe

OPTIONS = {"coarse_fraction": 0.0, "coarse_nside": 0, "fine_lr_scale": 0.25, "dense_warmup": 0.0,
           "vq_candidates": 0, "direction_features": 0.0, "prune": False, "measured_azimuths": 64,
           "runtime_fraction": 0.0, "runtime_samples": 32, "kmeans_weights": "uniform"}
"""dense_warmup: fraction of the steps trained with dense per-vertex features before they are k-means
quantised into the codebook (`NeuBRDF.quantize_from_dense`) and the VQ model trains on; 0, the default, is
the paper's end-to-end VQ training. Needs a model built with features="dense" (`config_for_source` picks it
when the option is > 0; an explicit features setting wins).

coarse_fraction: fraction of the steps trained first with dense features on a coarse grid, whose
interpolated features then start the model's own grid (`NeuBRDF.regrid`, coarse to fine); 0, the default,
starts at the model's N_side. With a dense warm-up the coarse steps are part of it (coarse_fraction <=
dense_warmup); without one the model must be built with features="dense". Why: at N_side 64 a slot sees about
1.3 corner reads per step of 8192 queries, and a fit from random features spends thousands of steps on them
(MERL-like gold-paint, 1200 steps of 8192: log error 0.0098 from scratch at N_side 64, 0.0012 after 600 steps
at N_side 16, still 0.0011 right after regridding to 64).

coarse_nside: N_side of the coarse grid; 0, the default, is a quarter of the model's (at least 1): 16 for the
paper's 64.

fine_lr_scale: the phases after the coarse one run their schedule at this factor of the learning rate: they
refine a grid that already fits (the gold-paint run above ended at 0.0014 with the full rate, 0.00094 at a
quarter).

vq_candidates: with a dense warm-up, the VQ phase keeps per grid slot the logits of its K nearest codewords
only (`VQFeatures.restrict`), so its steps cost O(K) per slot instead of O(2^b); 0 (default) keeps all 2^b,
the paper's estimator. 1 fixes every index at its k-means codeword (codebook and MLP still train).

direction_features: a scale s > 0 starts the first 3 feature channels of the dense grid (the coarse one, with
coarse_fraction) at s times each slot's direction (`NeuBRDF.init_direction_features`), so the MLP sees about
s (wi - reflect(wo)) from the first step; 0, the default, keeps the random start. Needs a dense grid: the model is
built with features="dense" unless a features setting says otherwise. The "dense" named recipe sets it. 10 is what we
use: on MERL-like chrome (dense N_side 64, 1500 steps, cosine_merl queries, log_cos_eps) image SSIM 0.75 at s = 1,
0.85 at 10; at N_side 16, 800 steps, 0.70 / 0.70 / 0.78 / 0.77 at 1 / 3 / 10 / 30
(benchmarks/studies/neubrdf/results/neubrdf_direction_init.md).

prune: sparse measurements (paper Sec. 3.2.1): before training, `model.prune(samples.wi, samples.wo)` on the
measured directions that the fit replays, so that pixels holding no measurement read their nearest
supervised ancestor's corners and the slots no pixel reads are not stored. Needs queries="replay".

kmeans_weights: how the k-means at the end of a dense warm-up weighs the slots' feature channels: "uniform" (the
default: plain k-means) or "sensitivity" (`neumat.fit.feature_sensitivity`: each slot's channels weighted by the
squared gradients of the fit's loss over SENSITIVITY_BATCHES batches, so codewords go where quantisation errors cost
the loss most). On MERL-like blue-metallic-paint2 (benchmarks/studies/neubrdf/results/neubrdf_table3_codebook.md) it quantises a
dense N_side 64 grid into 512 codewords as well as plain k-means does into 1024 (image MAE 0.0147 / 0.0148, 0.0212
plain), but after the CPU recipe's VQ phase the two end equal (0.0301 / 0.0304), hence the default.

runtime_fraction: the last fraction of the steps trains the model in its runtime form (1/4 corner weights,
`Config.runtime_interpolation` "uniform"), against the source averaged over each query's pixel pair
(`neumat.fit.pixel_pair_targets.PixelPairAverage`, runtime_samples points per query), at fine_lr_scale times
the rate; the other fractions (coarse_fraction, dense_warmup) are then fractions of the steps before it. 0, the
default, is the paper's training (inverse-distance weights throughout). Why: the shipped 1/4-weight model is
constant on every (wi pixel, wo pixel) pair, and a model trained with inverse-distance weights, evaluated at the
pixel centres, is far from the pair averages wherever the function varies within a pixel; on MERL-like chrome
(dense path, N_side 64) the shipped model renders at image MAE 0.036 and SSIM 0.85 where the pair averages
themselves render at 0.003 / 0.98 (benchmarks/studies/neubrdf/results/neubrdf_runtime_forms.md). A per-query log loss in the 1/4
form does not fix it (it fits something like the pair's median, which loses a sub-pixel peak's energy); pair
averages as targets do. The fitted model keeps interpolation "uniform" (the form it was trained for). Not with
queries="replay" (measured samples cannot be averaged over pixels) nor with an inverse-distance runtime (its
runtime form is the training form).

runtime_samples: points per query of the pixel-pair averages. Their noise falls as 1 / sqrt of it, and so does a
bias: a log-L1 loss fits the median of the noisy targets, below their mean where a sub-pixel peak spreads the
points (MERL-like steel, N_side 64: 6.5 % of the energy lost at 8, 4 % at 16, 1 % at 64). The recipe `dense` with
32 instead of 8 (the default until the Table 3 rows were fitted): steel image MAE 0.0035 -> 0.0027,
blue-metallic-paint2 0.0012 -> 0.0011, at about the same fit time (benchmarks/studies/neubrdf/results/neubrdf_runtime_forms.md).

measured_azimuths: with queries="replay" on an RGL file (`*_rgb.bsdf`), its measurement directions
(`neumat.fit.measured_samples.rgl_samples`) are the replayed samples; an isotropic file's single measured
incident azimuth is rotated to this many equally spaced azimuths."""

RECIPE = Recipe(steps=20000, batch_size=2 ** 14, lr=1e-2, betas=(0.9, 0.999), eps=1e-8, lr_decay=0.5,
                lr_decay_every=5000, ema=0.01, loss="log_cos", queries="cosine", seed=0, grad_clip=0.0,
                log_every=100, schedule="step", checkpoint_every=2000, options=dict(OPTIONS))

#: the paper's model in about 8 minutes on one CPU core, coarse to fine, then the codebook (module docstring)
CPU_RECIPE = Recipe(steps=5000, batch_size=2 ** 13, lr=1e-2, betas=(0.9, 0.999), eps=1e-8, lr_decay=0.5,
                    lr_decay_every=5000, ema=0.01, loss="log_cos", queries="cosine", seed=0, grad_clip=0.0,
                    log_every=100, schedule="halves", checkpoint_every=500,
                    options={**OPTIONS, "coarse_fraction": 0.4, "dense_warmup": 0.7, "vq_candidates": 8})
CPU_MINUTES = 8

#: `neumat fit --recipe dense`: the CPU recipe's steps and schedule on a dense grid (16 floats per slot: 1.6 MB at
#: fp16, 19x the paper's codebook model) with the direction-coded start (direction_features 10), half cosine and
#: half MERL-density queries and the floored log loss, the last 20 % of the steps in the runtime form against
#: pixel-pair averages (runtime_fraction). The lowest errors we measured: RGL Table 3 mean image MAE 0.0017
#: against the codebook's 0.0105, NBRDF's 0.0147 (benchmarks/studies/neubrdf/results/neubrdf_direction_init.md, before the
#: runtime phase); MERL-like chrome 0.0046 with the runtime phase, 0.0359 without, NBRDF 0.0077
#: (benchmarks/studies/neubrdf/results/neubrdf_runtime_forms.md). It does not quantise into a codebook (k-means loses the
#: direction code). About 6-9 minutes on one core.
DENSE_RECIPE = replace(CPU_RECIPE, loss="log_cos_eps", queries="cosine_merl",
                       options={**OPTIONS, "coarse_fraction": 0.4, "direction_features": 10.0,
                                "runtime_fraction": 0.2})
NAMED_RECIPES = {"dense": DENSE_RECIPE}

#: batches of the sensitivity estimate of option kmeans_weights="sensitivity" (at N_side 64 and 2^13 queries per
#: batch, each slot's corners are read about 100 times; about 10 s on one core)
SENSITIVITY_BATCHES = 80


def config_for_source(source, options: dict | None = None) -> dict:
    """Config defaults from the recipe options: dense features for a dense warm-up or a direction-coded start
    (`OPTIONS`)."""
    options = options or {}
    return {"features": "dense"} if warmup_fraction(options) > 0 or _direction_scale(options) > 0 else {}


def phases(ctx: FitContext) -> list[Phase]:
    """One online phase, or the stages the options ask for, in this order (each with the learning-rate schedule
    over its own steps; all on the measured samples of the source and with a pruned model under options
    queries="replay" / prune, see `_measured`):

    "coarse" (option coarse_fraction = c > 0): round(c steps) steps on a dense grid at coarse_nside (the model
    is regridded to it now); at its end `NeuBRDF.regrid` back to the model's N_side.
    "dense" (option dense_warmup = f > 0): the dense steps left up to round(f steps); at their end
    `quantize_from_dense` (with vq_candidates).
    "vq" (f > 0) or "fine" (c > 0, no warm-up: a dense model): the remaining steps.

    "runtime" (option runtime_fraction = r > 0): the last round(r steps) steps, in the runtime form against
    pixel-pair averages (see the option).

    Checkpoints hold the state of whichever grid the fit is on; a freshly built model loads any of them
    (`neumat.models.neubrdf.regridded_state`, `quantized_state`), so resuming is exact in every phase."""
    ctx = _measured(ctx)
    runtime_steps = _runtime_steps(ctx)
    nside = ctx.model.cfg.nside  # the model's own; a coarse phase regrids it now
    built = training_phases(ctx, ctx.recipe.steps - runtime_steps)
    if runtime_steps:
        built.append(_runtime_phase(ctx, runtime_steps, nside))
    return built


def training_phases(ctx: FitContext, steps: int) -> list[Phase]:
    """The phases before the runtime one: coarse, dense / fine, vq (see `phases`), `steps` in all. Also those of
    SharedNeuBRDF (`neumat.fit.recipes.shared_neubrdf`), whose model offers the same `regrid` and
    `quantize_from_dense`."""
    options, model = ctx.recipe.options, ctx.model
    frac = warmup_fraction(options)
    coarse = _coarse(options, model, frac)
    candidates = _candidates(options, model)
    weighting = _kmeans_weighting(options)
    if weighting != "uniform" and frac == 0:
        raise InputError(f"neubrdf recipe option kmeans_weights={weighting!r}: needs dense_warmup > 0 (it weighs the "
                         "k-means that ends the warm-up)")
    if candidates and frac == 0:
        raise InputError("neubrdf recipe option vq_candidates: needs dense_warmup > 0 (the candidates are "
                         "each slot's nearest codewords after the warm-up's k-means)")
    directions = _direction_scale(options)
    if frac == 0 and coarse == 0 and not directions:
        return [online_phase(ctx, steps=steps)]
    features = getattr(getattr(model, "cfg", None), "features", None)
    if features != "dense":
        why = (f"dense_warmup={frac}: needs a model built with features='dense' (the warm-up's features are "
               "quantised into the codebook afterwards)" if frac else
               f"coarse_fraction={coarse}: needs a model built with features='dense' (or a dense_warmup, to end "
               "with the codebook)" if coarse else
               f"direction_features={directions}: needs a model built with features='dense' (or a dense_warmup)")
        raise InputError(f"neubrdf recipe option {why}, got features={features!r}")
    fine_nside = model.cfg.nside
    coarse_steps = min(max(int(round(coarse * steps)), 1), steps) if coarse else 0
    dense_end = min(max(int(round(frac * steps)), 1), steps) if frac else steps
    if coarse:
        if options.get("prune", False):
            raise InputError("neubrdf recipe options coarse_fraction and prune: a pruned grid cannot be regridded; "
                             "use one or the other")
        model.regrid(_coarse_nside(options, fine_nside))
    if directions:
        model.init_direction_features(directions)  # a resumed fit loads its checkpoint over it
    if frac == 0 and coarse == 0:
        return [online_phase(ctx, steps=steps)]

    def leave_coarse():
        model.regrid(fine_nside)
        if frac and dense_end == coarse_steps:  # no dense steps at the model's N_side: quantise right away
            quantize()

    def quantize():
        weights = feature_sensitivity(ctx, SENSITIVITY_BATCHES, ctx.recipe.seed + 2) if weighting == "sensitivity" \
            else None
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
            phase.optimizer = _scaled(phase.optimizer, _fine_lr_scale(options))
    return [phase for phase in built if phase.steps > 0]


def _runtime_phase(ctx: FitContext, steps: int, nside: int) -> Phase:
    """`steps` steps of the model (N_side `nside`) in its 1/4-weight runtime form against the source's pixel-pair
    averages (option runtime_samples points per query, drawn from the fit's generator), at fine_lr_scale times
    the rate."""
    from ..pixel_pair_targets import PixelPairAverage

    model = ctx.model
    targets = PixelPairAverage(ctx.source, nside, _runtime_samples(ctx.recipe.options), ctx.generator)
    phase = online_phase(replace(ctx, source=targets, queries=query_draw(ctx), resuming=True), "runtime", steps)

    def start() -> None:
        model.cfg = replace(model.cfg, interpolation="uniform")

    phase.start = start
    phase.params = lambda: [p for p in model.parameters() if p.requires_grad]
    phase.optimizer = _scaled(phase.optimizer, _fine_lr_scale(ctx.recipe.options))
    return phase


def _runtime_steps(ctx: FitContext) -> int:
    """Steps of the runtime phase (0: none); InputError for a fraction out of range or a fit it cannot serve."""
    options = ctx.recipe.options
    frac = options.get("runtime_fraction", 0.0)
    if not isinstance(frac, (int, float)) or isinstance(frac, bool) or not 0 <= frac < 1:
        raise InputError(f"neubrdf recipe option runtime_fraction: expected a fraction in [0, 1), got {frac!r}")
    _runtime_samples(options)
    if frac == 0:
        return 0
    queries = ctx.queries if ctx.queries is not None else ctx.recipe.queries
    if queries == "replay":
        raise InputError(f"neubrdf recipe option runtime_fraction={frac}: needs a source it can evaluate anywhere "
                         "(its targets average the source over pixel pairs); queries=replay fits measured samples "
                         "only")
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


def _kmeans_weighting(options: dict) -> str:
    value = options.get("kmeans_weights", OPTIONS["kmeans_weights"])
    if value not in ("uniform", "sensitivity"):
        raise InputError(f"neubrdf recipe option kmeans_weights: expected 'uniform' or 'sensitivity', got {value!r}")
    return value


def _runtime_samples(options: dict) -> int:
    k = options.get("runtime_samples", OPTIONS["runtime_samples"])
    if isinstance(k, bool) or not isinstance(k, int) or k < 1:
        raise InputError(f"neubrdf recipe option runtime_samples: expected an integer >= 1, got {k!r}")
    return k


def _direction_scale(options: dict) -> float:
    scale = options.get("direction_features", 0.0)
    if not isinstance(scale, (int, float)) or isinstance(scale, bool) or not 0 <= scale < float("inf"):
        raise InputError(f"neubrdf recipe option direction_features: expected a scale >= 0 (0: off), got {scale!r}")
    return float(scale)


def _scaled(make, factor: float):
    """An optimiser factory like `make` whose param groups learn at `factor` times their rate ("lr_scale")."""
    def scaled(params, lr, betas, eps):
        opt = make(params, lr, betas, eps)
        for group in opt.param_groups:
            group["lr_scale"] = group.get("lr_scale", 1.0) * factor
        return opt
    return scaled


def _fine_lr_scale(options: dict) -> float:
    scale = options.get("fine_lr_scale", 0.25)
    if not isinstance(scale, (int, float)) or isinstance(scale, bool) or not 0 < scale <= 1:
        raise InputError(f"neubrdf recipe option fine_lr_scale: expected a factor in (0, 1], got {scale!r}")
    return float(scale)


def _coarse(options: dict, model, warmup: float) -> float:
    frac = options.get("coarse_fraction", 0.0)
    if not isinstance(frac, (int, float)) or isinstance(frac, bool) or not 0 <= frac < 1:
        raise InputError(f"neubrdf recipe option coarse_fraction: expected a fraction in [0, 1), got {frac!r}")
    if frac and warmup and frac > warmup:
        raise InputError(f"neubrdf recipe option coarse_fraction={frac}: the coarse steps are part of the dense "
                         f"warm-up, so at most dense_warmup={warmup}")
    if frac:
        _coarse_nside(options, getattr(getattr(model, "cfg", None), "nside", None))
    return float(frac)


def _coarse_nside(options: dict, fine: int | None) -> int:
    """The coarse grid's N_side: option coarse_nside, or 0 for a quarter of the model's `fine` N_side (at least 1)."""
    n = options.get("coarse_nside", 0)
    if n == 0 and not isinstance(n, bool) and fine is not None:
        n = max(fine // 4, 1)
    if isinstance(n, bool) or not isinstance(n, int) or n < 1 or n & (n - 1) or fine is None or n >= fine:
        raise InputError(f"neubrdf recipe option coarse_nside: expected a power of two below the model's N_side "
                         f"{fine} (0: a quarter of it), got {options.get('coarse_nside', 0)!r}")
    return n


def _candidates(options: dict, model) -> int:
    k = options.get("vq_candidates", 0)
    most = 2 ** model.cfg.index_bits
    if isinstance(k, bool) or not isinstance(k, int) or not 0 <= k <= most:
        raise InputError(f"neubrdf recipe option vq_candidates: expected 0 (all codewords) or 1 .. {most} "
                         f"(2^index_bits), got {k!r}")
    return k


def warmup_fraction(options: dict) -> float:
    frac = options.get("dense_warmup", 0.0)
    if not isinstance(frac, (int, float)) or isinstance(frac, bool) or not 0 <= frac < 1:
        raise InputError(f"neubrdf recipe option dense_warmup: expected a fraction in [0, 1), got {frac!r}")
    return float(frac)


def _measured(ctx: FitContext) -> FitContext:
    """The fit's context for sparse measurements: with queries "replay" the source must hold measurement
    samples (a `MeasuredSamples`, or an RGL file whose measurement directions `rgl_samples` gives, then the
    source of the fit); with option prune the model is pruned to their directions first (`NeuBRDF.prune`,
    deterministic, so a resumed fit prunes the same way). InputError for prune without replay queries and
    for replay on a source without measurement samples."""
    from ...reflectance.measured import RglMaterial
    from ..measured_samples import MeasuredSamples, rgl_samples

    prune = ctx.recipe.options.get("prune", False)
    if not isinstance(prune, bool):
        raise InputError(f"neubrdf recipe option prune: expected true or false, got {prune!r}")
    queries = ctx.queries if ctx.queries is not None else ctx.recipe.queries
    if queries != "replay":
        if prune:
            raise InputError(f"neubrdf recipe option prune=true: needs queries=replay (the model is pruned to the "
                             f"measured directions and must train on them), got queries={queries!r}")
        return ctx
    source = ctx.source
    if isinstance(source, RglMaterial):
        source = rgl_samples(source, ctx.recipe.options.get("measured_azimuths", 64))
    elif not isinstance(source, MeasuredSamples):
        name = source.describe() if hasattr(source, "describe") else type(source).__name__
        raise InputError(f"neubrdf with queries=replay{' and prune=true' if prune else ''}: the source "
                         f"{name!r} holds no measurement samples; give an RGL *_rgb.bsdf file or "
                         f"neumat.fit.measured_samples.MeasuredSamples")
    if prune:
        ctx.model.prune(source.wi.to(ctx.device), source.wo.to(ctx.device))
    return replace(ctx, source=source)
