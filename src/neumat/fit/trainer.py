"""The one trainer: fit any learned model to its source, in one or several phases.

A fit is a list of phases (`neumat.fit.phase`) from the model's method (`neumat.fit.method`). All phases share one loop:
schedule, EMA, gradient clipping, the non-finite guard (`neumat.fit.rollback`), progress, and checkpoints
from which `resume=True` continues bit for bit. Model hooks (`neumat.models.base.LearnedMaterial`):
`on_step`, `init_from_targets`, `optimizer`.

Details: docs/notes/fit.md, section `neumat.fit.trainer`.
"""
from __future__ import annotations

import math
import os
import sys
import time
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable

import torch
from torch import nn

from ..core.allocator import retain_freed_memory
from ..core.config import config_to_dict
from ..core.errors import DataFormatError, InputError, UnknownNameError
from ..core.query import Query
from ..core.threads import adapt as adapt_threads
from ..io.atomic import atomic_write
from ..models.base import LearnedMaterial
from ..warp.hemisphere import sample_cosine_hemisphere
from neumat.fit import footprint_queries  # noqa: F401  (registers the "footprint" query sampler)
from .ema import EMA
from .measured_samples import MeasuredSamples
from .phase import FitContext, Phase, check_source, model_name, online_phase, online_targets, query_draw
from .preset import default_recipe
from .recipe import Recipe, check_recipe, learning_rate
from .method import phases_for, typed_options
from .rollback import CHECKPOINT_KEYS, NonFiniteGuard


@dataclass
class FitResult:
    """model: the fitted model (the EMA weights when the recipe uses an EMA), in eval mode.
    history: one record {"step", "phase", "loss", <each named loss>, "loss_median", "lr", "seconds"} per
    `log_every` steps and at the end of each phase (losses averaged over the steps since the last record,
    "loss_median" the median of those steps' losses), with "rollback": the
    step whose state was restored, when the fit rolled back since the last record (`neumat.fit.rollback`).
    seconds: training time (summed over resumed runs). steps: steps taken in total. recipe: the recipe run
    (with the steps actually taken). cpu_seconds: this process's CPU seconds over the fit, all its threads (summed
    over resumed runs; None when a checkpoint written before they were recorded was resumed): what the fit cost."""

    model: nn.Module
    history: list[dict]
    seconds: float
    steps: int
    recipe: Recipe | None = None
    cpu_seconds: float | None = None
    warnings: list[str] = field(default_factory=list)
    """What went wrong without stopping the fit: a phase that ended far above its best loss after its warm-up
    (`ENDS_ABOVE_BEST`, `WARMUP_FRACTION`), a loss spike (`SPIKE`), an output that collapsed (`COLLAPSED`)."""


def fit(model: nn.Module, source: Any, recipe: Recipe | None = None, *, steps: int | None = None,
        device: str | torch.device | None = None, progress: bool = True, checkpoint: str | Path | None = None,
        resume: bool = False, callback: Callable[[dict], None] | None = None, loss: str | nn.Module | None = None,
        queries: str | Callable | None = None) -> FitResult:
    """Fit `model` to `source` and return a FitResult; `model` itself is trained in place (and receives the
    EMA weights at the end when the recipe uses an EMA).

    source:     a Material for online fits; what the model's recipe phases read otherwise (translucent
                observations, a BTF table).
    recipe:     defaults to the recipe of the model's default preset for this source and device
                (`neumat.fit.preset.default_recipe`); `steps` overrides recipe.steps (split over the phases by
                recipe.phase_split).
    device:     torch device for the model, the queries and the targets; default: the model's.
    checkpoint: file written every `recipe.checkpoint_every` steps, at the end of every phase and at the end;
                with `resume=True` an existing file is loaded and the fit continues from it (it must have the
                same recipe).
    callback:   called with every history record, after the checkpoint of that step.
    loss:       a LOSSES name or a loss module, overriding recipe.loss.
    queries:    a QUERY_SAMPLERS name or a `draw(n, generator, device) -> Query`, overriding recipe.queries.
    """
    if not isinstance(model, LearnedMaterial):
        raise InputError(f"fit: model must be a neumat.models.base.LearnedMaterial (a torch nn.Module "
                         f"implementing neumat.Material), got {type(model).__name__}")
    retain_freed_memory()  # a step's large temporaries reused, not faulted in afresh (core/allocator.py)
    name = model_name(model)
    dev = torch.device(device) if device is not None else _model_device(model)
    recipe = replace(recipe if recipe is not None else default_recipe(model, source, dev))
    if steps is not None:
        recipe.steps = steps
    check_recipe(recipe)
    typed_options(name, recipe.options)
    if resume and checkpoint is None:
        raise InputError("fit: resume=True needs a checkpoint path")
    model.to(dev).train()
    gen = torch.Generator(device=dev).manual_seed(recipe.seed)
    resuming = resume and Path(checkpoint).is_file()
    ctx = FitContext(model, source, recipe, dev, gen, resuming, loss, queries)
    try:
        build = phases_for(name)
    except UnknownNameError:  # a model without a method, fitted with an explicit recipe
        build = None
    started = time.perf_counter()  # the fit's seconds include the phase builder's own work (e.g. GGX's trial starts)
    cpu_started = time.process_time()
    phases = build(ctx) if build is not None else [online_phase(ctx)]
    ema = EMA(model, recipe.ema) if recipe.ema > 0 else None
    state = {"step": 0, "history": [], "seconds": 0.0, "cpu_seconds": 0.0, "running": {}, "optimizer": None,
             "guard": {}}
    if resuming:
        state = _load_checkpoint(checkpoint, recipe, model, ema, phases, gen, source)
    total = sum(p.steps for p in phases)
    t0, cpu0 = started - state["seconds"], cpu_started - state["cpu_seconds"]
    with _Progress(progress, total, state["step"], name) as bar:
        guard = NonFiniteGuard(model, ema, name, state.pop("guard"), report=bar.note)
        begin = 0
        for index, phase in enumerate(phases):
            end = begin + phase.steps
            if state["step"] < end:  # each phase's steps cost their own: its estimate is measured in it
                bar.start_phase(phase.name, end, [(p.name, p.steps) for p in phases[index + 1:]])
            if phase.start is not None:
                phase.start()
            if state["step"] >= end:
                begin = end
                continue
            params = phase.params() if callable(phase.params) else phase.params
            opt = _optimizer(phase, params, recipe)
            if opt is not None and state["optimizer"] is not None:
                opt.load_state_dict(state["optimizer"])
            state["optimizer"] = None
            guard.start_phase(opt, max(state["step"], begin), resumed=state["step"] > begin)
            running: dict[str, torch.Tensor] = {k: v.to(dev) for k, v in state["running"].items()}
            slow = None if phase.slow_from is None else begin + phase.slow_from
            if slow is not None and max(state["step"], begin) < slow < end:
                bar.note(f"fit {name}: phase {phase.name!r} turns slower at step {slow} (e.g. batches traced online "
                         "from there); the time estimate is measured again then")
            for step in range(max(state["step"], begin), end):
                if step == slow:
                    bar.remeasure()
                scheduled_lr = learning_rate(recipe, step - begin, phase.steps)
                lr = scheduled_lr * guard.lr_factor
                if opt is not None:
                    for group in opt.param_groups:
                        group["lr"] = lr * group.get("lr_scale", 1.0)
                model.on_step(step, total)
                if ema is not None:
                    ema.shadow.on_step(step, total)
                values = phase.losses(step - begin)
                finite = True
                if opt is not None:
                    opt.zero_grad(set_to_none=True)
                    sum(values.values()).backward()
                    norm = _gradient_norm(params)
                    finite = bool(torch.isfinite(norm))
                    if finite:
                        if recipe.grad_clip > 0:
                            _scale_gradients(params, norm, recipe.grad_clip)
                        opt.step()
                        if ema is not None:
                            ema.update(model)
                    else:  # skip the step (the guard halves the learning rate, or rolls back)
                        opt.zero_grad(set_to_none=True)
                    guard.after_step(finite, step + 1, phase.name, scheduled_lr)
                if finite:
                    for k, v in values.items():
                        running[k] = running.get(k, torch.zeros((), device=dev)) + v.detach()
                    running["_steps"] = running.get("_steps", torch.zeros((), device=dev)) + 1
                    step_loss = sum(v.detach() for v in values.values()).reshape(1)
                    running["_window"] = torch.cat([running["_window"], step_loss]) if "_window" in running \
                        else step_loss
                done = step + 1
                bar.advance()
                if (threads := adapt_threads()) is not None:  # only under a command given no thread count
                    bar.note(f"fit {name}: {threads}")
                    bar.remeasure()  # the rate changes with the threads: the time estimate is measured again
                if done % recipe.log_every == 0 or done % recipe.checkpoint_every == 0 or done == end:
                    guard.check(done, phase.name, scheduled_lr, snapshot=done < end)
                record = None
                if done % recipe.log_every == 0 or done == end:
                    record = _record(running, done, phase.name, lr, time.perf_counter() - t0) | guard.pop_rollback()
                    if phase.on_record is not None:
                        phase.on_record(record)
                if done == end:
                    guard.end_phase()
                    if phase.after is not None:
                        phase.after()
                        if ema is not None:
                            ema.reset(model)
                if record is not None:
                    state["history"].append(record)
                    bar.show(record, total)
                if checkpoint is not None and (done % recipe.checkpoint_every == 0 or done == end):
                    state.update(step=done, seconds=time.perf_counter() - t0, cpu_seconds=time.process_time() - cpu0,
                                 running=running,
                                 optimizer=opt.state_dict() if opt is not None and done < end else None)
                    _save_checkpoint(checkpoint, recipe, model, ema, phases, gen, source,
                                     state | guard.checkpoint_state(done))
                if callback is not None and state["history"] and state["history"][-1]["step"] == done:
                    callback(state["history"][-1])
            state["step"] = end
            state["running"] = {}
            begin = end
    seconds, cpu_seconds = time.perf_counter() - t0, time.process_time() - cpu0
    if ema is not None:
        model.load_state_dict(ema.state_dict())
    model.train(False)
    problems = ended_above_best(state["history"], name) + loss_spikes(state["history"], name, recipe.grad_clip) \
        + collapsed_output(ctx) + energy_gain(ctx)
    for text in problems:
        warnings.warn(text, FitWarning, stacklevel=2)
    return FitResult(model=model, history=state["history"], seconds=seconds, steps=total,
                     recipe=replace(recipe, steps=total), warnings=problems,
                     cpu_seconds=None if math.isnan(cpu_seconds) else cpu_seconds)


#: a phase whose last recorded loss is this many times its lowest says so: fits that blew up used to end silently.
#: The records compared are each window's median step loss ("loss_median"), not its mean: on a near-mirror a batch's
#: loss is carried by a few queries (issue 55's polished plate: per-step p99 15x the median, single steps 1e3-1e4x),
#: so one step could lift a 50-step mean 2.3x above the fit's lowest while its median sat at 1.2x and the fit's
#: FLIP was the best it had reached (benchmarks/studies/multiscale/results/selection_free.md)
ENDS_ABOVE_BEST = 2.0

#: the records of a phase's first this fraction of steps are not a "lowest" to compare its end with: they average
#: the loss of a model near its initialisation, which a relative loss can score far below where a sound fit ends
#: (issue 55, neumip-frame on a polished metal: benchmarks/studies/multiscale/results/polished_metal_stability.md)
WARMUP_FRACTION = 0.1


#: a record this many times the lowest before it in its phase is a spike: one step's huge gradient inflates Adam's
#: second moment, and with beta2 0.999 the learning then stalls for hundreds of steps, far above where it was,
#: without ending above its lowest (issue 55: neumip-frame on Metal027 crops, 1.6 -> 2.3e5 -> stuck at 2.0,
#: benchmarks/studies/multiscale/results/selection_free.md)
SPIKE = 1000.0


class FitWarning(UserWarning):
    """A fit finished, but not well (it ended far above its best loss, or its loss spiked on the way)."""


def record_loss(record: dict) -> float:
    """The loss of a history record that the end-of-fit check compares: its window's median step loss, or its mean
    for records written before medians were kept."""
    return record.get("loss_median", record["loss"])


def ended_above_best(history: list[dict], name: str) -> list[str]:
    """One message per phase of `history` whose last record's loss (`record_loss`) is more than ENDS_ABOVE_BEST
    times its lowest after the phase's first WARMUP_FRACTION of steps (phases with at least two finite, positive
    records there; a phase starts where the one recorded before it ended)."""
    out = []
    begin = 0
    for phase in dict.fromkeys(r["phase"] for r in history):
        records = [r for r in history if r["phase"] == phase]
        end = records[-1]["step"]
        settled = begin + WARMUP_FRACTION * (end - begin)
        begin = end
        losses = [(record_loss(r), r["step"]) for r in records
                  if r["step"] > settled and math.isfinite(record_loss(r))]
        if len(losses) < 2 or min(losses)[0] <= 0:
            continue
        (best, at), last = min(losses), losses[-1][0]
        if last > ENDS_ABOVE_BEST * best:
            out.append(f"fit {name}: phase {phase!r} ended at loss {last:.4g}, {last / best:.1f}x its lowest "
                       f"({best:.4g} at step {at}; medians of the steps between records): the fit became "
                       "unstable; try a lower learning rate (--set lr=...) or another seed")
    return out


def loss_spikes(history: list[dict], name: str, grad_clip: float = 0.0) -> list[str]:
    """One message per phase of `history` with a record more than SPIKE times the lowest finite, positive record
    before it in that phase (the largest such spike of the phase); its advice: clipping the gradient, unless the
    fit clipped already (`grad_clip` > 0), then a lower learning rate."""
    out = []
    for phase in dict.fromkeys(r["phase"] for r in history):
        lowest, worst = math.inf, None
        for r in (r for r in history if r["phase"] == phase and math.isfinite(r["loss"])):
            if r["loss"] > SPIKE * lowest and (worst is None or r["loss"] / lowest > worst[0]):
                worst = (r["loss"] / lowest, r, lowest)
            if r["loss"] > 0:
                lowest = min(lowest, r["loss"])
        if worst is not None:
            ratio, r, before = worst
            out.append(f"fit {name}: phase {phase!r} spiked to loss {r['loss']:.4g} at step {r['step']}, "
                       f"{ratio:.3g}x its lowest before ({before:.4g}); a spike can stall Adam for hundreds of "
                       "steps: if the fit ended poorly, try "
                       + (f"a lower learning rate (--set recipe.lr=...; gradients were clipped at norm {grad_clip:g})"
                          if grad_clip > 0 else "--set recipe.grad_clip=1"))
    return out


def collapsed_output(ctx: FitContext) -> list[str]:
    """One message when the fitted model's output at COLLAPSE_QUERIES of the fit's queries (drawn with seed
    recipe.seed + 2) is near zero or near constant (mean |output|, or its spread over the queries in every channel,
    below COLLAPSED times the source's), for sources that give online targets; none for a source without variation.
    After a full recipe such a network died early: its loss sits flat at its lowest, so neither loss check sees
    it (a fit of a few steps can also end here, still near its initialisation)."""
    try:
        check_source(ctx.model, ctx.source)
        draw = query_draw(ctx)
    except InputError:  # not an online source (translucent observations, a BTF table)
        return []
    q = draw(COLLAPSE_QUERIES, torch.Generator(device=ctx.device).manual_seed(ctx.recipe.seed + 2), ctx.device)
    target = online_targets(ctx, q).double().reshape(COLLAPSE_QUERIES, -1)
    with torch.no_grad():
        pred = ctx.model.eval(q).double().reshape(COLLAPSE_QUERIES, -1)
    size_t, size_p = target.abs().mean(), pred.abs().mean()
    spread_t, spread_p = target.std(0), pred.std(0)
    if not (torch.isfinite(size_p) and size_t > 0 and bool((spread_t > 0).any())):
        return []
    if size_p < COLLAPSED * size_t:
        what = f"near zero (mean |output| {size_p:.3g} against the source's {size_t:.3g}"
    elif bool((spread_p < COLLAPSED * spread_t).all()):
        what = (f"near constant (its spread over the queries at most {float((spread_p / spread_t).max()):.2g}x "
                "the source's")
    else:
        return []
    return [f"fit {model_name(ctx.model)}: the fitted model learned none of the source's variation: its output is "
            f"{what}, at {COLLAPSE_QUERIES} of the fit's queries); after a full recipe this is a network that died "
            "early: try a lower learning rate (--set recipe.lr=...) or another seed"]


def energy_gain(ctx: FitContext) -> list[str]:
    """One message when a fitted BRDF reflects more light than it receives: its directional albedo (per channel, a
    cosine-weighted estimate from ENERGY_SAMPLES directions drawn with seed recipe.seed + 3, the same for the
    source) exceeds 1, and the source's own where the source can be evaluated anywhere, by more than ENERGY_MARGIN
    beyond three standard errors, at an incident elevation of ENERGY_ELEVATIONS at 4 azimuths. Why: a fit to sparse
    measurements is unconstrained between them, and where they are few (grazing outgoing directions, far from an
    RGL file's specular peak) no loss sees it: the neubrdf suite's replay fits of cc_ibiza_sunset reach albedo
    7-11 at 80 degrees against the file's 0.3, and their losses end at their lowest. None for spatially varying or
    full-sphere models."""
    model, source, dev = ctx.model, ctx.source, ctx.device
    if getattr(model, "spatially_varying", False) or getattr(model, "full_sphere", False):
        return []
    try:
        check_source(model, source)
    except InputError:
        return []
    theta = torch.tensor(ENERGY_ELEVATIONS, dtype=torch.float64).deg2rad().repeat_interleave(4)
    phi = torch.arange(4, dtype=torch.float64).repeat(len(ENERGY_ELEVATIONS)) * (math.pi / 2)
    wi = torch.stack([theta.sin() * phi.cos(), theta.sin() * phi.sin(), theta.cos()], -1)
    gen = torch.Generator().manual_seed(ctx.recipe.seed + 3)
    wo = sample_cosine_hemisphere(torch.rand(ENERGY_SAMPLES, 2, generator=gen, dtype=torch.float64))
    m, n = len(wi), ENERGY_SAMPLES
    q = Query(wi.repeat_interleave(n, 0).float().to(dev), wo.repeat(m, 1).float().to(dev))
    with torch.no_grad():
        pred = (model.eval(q).double().cpu() * math.pi).reshape(m, n, -1)
    sparse = isinstance(source, MeasuredSamples)  # answers other queries by its nearest sample: no albedo of its own
    try:
        ref = None if sparse else (online_targets(ctx, q).double().cpu() * math.pi).reshape(m, n, -1)
    except InputError:
        ref = None
    albedo, stderr = pred.mean(1), pred.std(1) / math.sqrt(n)
    if ref is None:
        bound, excess_err = torch.ones_like(albedo), stderr
    else:
        bound = ref.mean(1).clamp(min=1.0)
        excess_err = torch.where(ref.mean(1) > 1, (pred - ref).std(1) / math.sqrt(n), stderr)
    score = (albedo - bound) - 3 * excess_err
    if not bool(torch.isfinite(albedo).all()) or float(score.max()) <= ENERGY_MARGIN:
        return []
    at = int(score.max(1).values.argmax())
    worst = int(albedo[at].argmax())
    where = "normal incidence" if at < 4 else \
        f"{math.degrees(float(theta[at])):.0f} degrees incidence, azimuth {math.degrees(float(phi[at])):.0f}"
    against = "at most 1 for a physical BRDF"
    if ref is not None:
        against += f"; the source's {float(ref.mean(1)[at, worst]):.3g}"
    if not sparse:
        advice = "the fit overshoots where its queries are few: try more steps (--set recipe.steps=...) or another seed"
    else:
        advice = ("where the measurements are few (far from the specular peak, at grazing angles) the fit is "
                  "unconstrained, and renders too bright there: measure more directions")
        if (ctx.queries or ctx.recipe.queries) != "replay_cells":
            advice += ", or draw the measurements balanced over directions (--set queries=replay_cells)"
    return [f"fit {model_name(model)}: the fitted model reflects more light than it receives: directional albedo "
            f"{float(albedo[at, worst]):.3g} (channel {worst}) at {where} ({against}); {advice}"]


#: the incident elevations (degrees) `energy_gain` checks: above 80 both a source's and a model's albedo rise
#: toward grazing, where a measured table has few samples
ENERGY_ELEVATIONS = (0.0, 10.0, 20.0, 30.0, 40.0, 50.0, 60.0, 70.0, 80.0)

#: outgoing directions per incident one in `energy_gain`: 36 x 2048 evaluations, a fraction of a second
ENERGY_SAMPLES = 2048

#: an albedo this far above 1 (or above the source's, where that is more) beyond its noise is an energy gain
ENERGY_MARGIN = 0.05


#: the queries `collapsed_output` draws (a fraction of a second for any model here)
COLLAPSE_QUERIES = 4096

#: an output this many times the source's size, or spread, has collapsed: neural-appearance at lr 1e-2 on Metal027
#: died in its encoder phase's first 200 steps, its loss flat at its lowest to the end and its output 3e-27 of the
#: source's, without a warning (benchmarks/studies/neural_appearance/results/learning_rate.md); the sound fit of the
#: same set reaches 1.01x the source's mean and 1.05x its spread
COLLAPSED = 0.01


def _record(running: dict, done: int, phase: str, lr: float, seconds: float) -> dict:
    """One history record from the running sums (which it resets): each named loss averaged over the steps
    taken since the last record, "loss" their sum (NaN when every step since was skipped), and "loss_median" the
    median of those steps' losses (what `ended_above_best` reads: a batch loss can be heavy-tailed)."""
    n = float(running.pop("_steps", torch.zeros(())).item())
    window = running.pop("_window", None)
    median = window.median().item() if window is not None and window.numel() else math.nan
    losses = {k: v.item() / n if n else math.nan for k, v in running.items()}
    running.clear()
    extra = {k: v for k, v in losses.items() if k != "loss"}
    loss = losses["loss"] if "loss" in losses and not extra else sum(losses.values()) if n else math.nan
    return {"step": done, "phase": phase, "loss": loss, **extra, "loss_median": median, "lr": lr, "seconds": seconds}


def _optimizer(phase: Phase, params: list[nn.Parameter] | None, recipe: Recipe) -> torch.optim.Optimizer | None:
    """The optimiser of `phase` on `params` (the phase's, resolved when it starts); None for a solver phase."""
    if params is None:
        return None
    if not params:
        raise InputError(f"fit: phase {phase.name!r} has no trainable parameters")
    make = phase.optimizer or (lambda params, lr, betas, eps: torch.optim.Adam(params, lr=lr, betas=betas, eps=eps))
    return make(params, recipe.lr, tuple(recipe.betas), recipe.eps)


def _gradient_norm(params: list[torch.Tensor]) -> torch.Tensor:
    """Joint 2-norm of all gradients (dense or sparse); 0 when there are none."""
    grads = [p.grad.coalesce().values() if p.grad.is_sparse else p.grad for p in params if p.grad is not None]
    if not grads:
        return torch.zeros(())
    return torch.linalg.vector_norm(torch.stack([torch.linalg.vector_norm(g) for g in grads]))


def _scale_gradients(params: list[torch.Tensor], total: torch.Tensor, max_norm: float) -> None:
    """Scale all gradients so that their joint 2-norm `total` becomes at most `max_norm`."""
    scale = (max_norm / (total + 1e-6)).clamp(max=1.0)
    for p in params:
        if p.grad is not None:
            p.grad.mul_(scale)


def _model_device(model: nn.Module) -> torch.device:
    for t in list(model.parameters()) + list(model.buffers()):
        return t.device
    return torch.device("cpu")


def _source_generators(source: Any) -> list[torch.Generator]:
    """The generators a source draws from for itself (an SVBRDF's footprint samples: `source.generator`), for
    every source of a set: state the checkpoint must hold for a resumed fit to be exact."""
    sources = source if isinstance(source, (list, tuple)) else [source]
    return [s.generator for s in sources if isinstance(getattr(s, "generator", None), torch.Generator)]


def _rng_states(gen: torch.Generator, source: Any) -> dict:
    states = {"queries": gen.get_state(), "torch": torch.get_rng_state(),
              "sources": [g.get_state() for g in _source_generators(source)]}
    if torch.cuda.is_available():
        states["cuda"] = torch.cuda.get_rng_state_all()
    return states


def _save_checkpoint(path, recipe, model, ema, phases, gen, source, state) -> None:
    blob = {"recipe": config_to_dict(recipe), "model": model.state_dict(),
            "ema": ema.state_dict() if ema is not None else None,
            "stateful": [[m.state_dict() for m in p.stateful] for p in phases],
            "rng": _rng_states(gen, source), **state}
    path = Path(path)
    atomic_write(path, lambda tmp: torch.save(blob, tmp))  # never leave a half-written checkpoint nor its tmp


def _load_checkpoint(path, recipe, model, ema, phases, gen, source) -> dict:
    try:
        blob = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # noqa: BLE001 - any unreadable file is reported the same way
        raise DataFormatError(f"checkpoint {str(path)!r}: cannot be read ({e})") from None
    if not isinstance(blob, dict) or "stateful" not in blob:
        raise DataFormatError(f"checkpoint {str(path)!r}: not a checkpoint of this neumat version's trainer")
    saved = dict(blob["recipe"])
    now = config_to_dict(recipe)
    if saved != now:
        diff = sorted(k for k in now if saved.get(k) != now[k])
        raise InputError(f"checkpoint {str(path)!r} was written with a different recipe (fields {', '.join(diff)}); "
                         "resume with the same recipe or start a new checkpoint")
    model.load_state_dict(blob["model"])
    if ema is not None:
        ema.load_state_dict(blob["ema"])
    for phase, states in zip(phases, blob["stateful"]):
        for module, st in zip(phase.stateful, states):
            module.load_state_dict(st)
    rng = blob["rng"]
    gen.set_state(rng["queries"])
    torch.set_rng_state(rng["torch"])
    for g, st in zip(_source_generators(source), rng["sources"]):
        g.set_state(st)
    if "cuda" in rng and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(rng["cuda"])
    state = {k: blob[k] for k in ("step", "history", "seconds", "running", "optimizer")}
    state["cpu_seconds"] = float(blob.get("cpu_seconds", math.nan))  # checkpoints before it: unknown
    return state | {"guard": {k: blob[k] for k in CHECKPOINT_KEYS if k in blob}}


#: a fit whose estimated time exceeds this many seconds suggests a shorter run when it announces its estimate
LONG_FIT_SECONDS = 15 * 60
#: steps not counted in the announced estimate (the first steps pay one-off costs: allocation, caches)
WARMUP_STEPS = 2
#: the fewest steps an estimate is measured on (a first step after a change, e.g. online batches, costs extra)
MIN_COUNTED = 3
#: the announced estimate is checked at half REESTIMATE_AFTER times as many steps after it as it was measured on, then
#: each time at twice as many, and said again when the speed since the previous check would end the phase more than
#: REESTIMATE_FACTOR times later or sooner
REESTIMATE_AFTER, REESTIMATE_FACTOR = 3, 1.5


class _Progress:
    """Progress of a fit on stderr: a rich bar with the live loss on a terminal, a plain line every 30 s (and at
    the end of each phase) otherwise; nothing when `enabled` is false. Either way each phase announces once, after
    its first steps, the time its remaining steps will take, measured on this source and machine (not a constant;
    later phases, whose steps cost their own, are named with their step counts and measured when they start), and
    once more if the steps after it run at more than `REESTIMATE_FACTOR` times or less than its inverse (a load
    that came or went: the first estimate would not hold)."""

    def __init__(self, enabled: bool, total: int, start: int, name: str) -> None:
        enabled = enabled and not os.environ.get("NEUMAT_QUIET")  # a command's --quiet (neumat.cli.common)
        self.enabled, self.total, self.done, self.name = enabled, total, start, name
        self.phase_end = total  # the last step of the phase the estimates measure
        self.terminal = enabled and sys.stderr.isatty()
        self.t0 = self.last_line = time.perf_counter()
        self.start, self.warned, self.t_warm = start, False, self.t0
        # (when, at which step, the estimate, (time, step) of the last check, steps after it of the next check)
        self.announced: tuple | None = None
        self.phase_note = ""
        if self.terminal:
            from rich.console import Console
            from rich.progress import (BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn,
                                       TimeRemainingColumn)
            self.bar = Progress(TextColumn(f"fit {name}"), BarColumn(), MofNCompleteColumn(),
                                TextColumn("{task.fields[phase]} loss {task.fields[loss]}"), TimeElapsedColumn(),
                                TimeRemainingColumn(), console=Console(stderr=True))
            self.task = self.bar.add_task("fit", total=total, completed=start, loss="-", phase="")

    def __enter__(self) -> "_Progress":
        if self.terminal:
            self.bar.__enter__()
        return self

    def __exit__(self, *exc) -> None:
        if self.terminal:
            self.bar.__exit__(*exc)

    def _eta(self) -> float:
        estimate = self.estimate()
        if estimate is not None:
            return estimate
        rate = (time.perf_counter() - self.t_warm) / max(self.done - self.start, 1)
        return rate * (self.phase_end - self.done)

    def start_phase(self, name: str, end: int, later: list[tuple[str, int]]) -> None:
        """A phase begins (`name`, ending at step `end`, with phases `later` (name, steps) after it): its estimate
        is of its own steps, measured on them, and names the later phases, measured when they start (their steps cost
        their own: NeuBRDF's coarse steps half its VQ ones, NeuPreSS's sampler steps 8x its appearance steps)."""
        self.remeasure()
        self.phase_end = end
        when = "it starts" if len(later) == 1 else "they start"
        self.phase_note = "" if not later else \
            f" of phase {name!r}; then {', '.join(f'{n!r} ({k} steps)' for n, k in later)}, measured when {when}"

    def remeasure(self) -> None:
        """Measure the time estimate again from the next step on and announce it once more (the steps from here
        cost differently: a phase's `slow_from`, or a change of torch threads)."""
        self.start, self.warned, self.t_warm = self.done, False, time.perf_counter()
        self.announced = None

    def estimate(self) -> float | None:
        """Seconds still to go in this phase at the speed of its steps after the first WARMUP_STEPS, or None before
        any."""
        counted = self.done - self.start - WARMUP_STEPS
        if counted < 1:
            return None
        return (time.perf_counter() - self.t_warm) / counted * (self.phase_end - self.done)

    def advance(self) -> None:
        self.done += 1
        if self.done - self.start == WARMUP_STEPS:
            self.t_warm = time.perf_counter()
        if self.terminal:
            self.bar.advance(self.task)
        counted = self.done - self.start - WARMUP_STEPS
        if self.enabled and not self.warned and counted > 0 and (  # slow steps: after 10 s, but 3 steps at least
                counted >= 20 or (counted >= MIN_COUNTED and time.perf_counter() - self.t_warm > 10)
                or self.done == self.phase_end):
            self.warned = True
            eta = self.estimate()
            now = time.perf_counter()
            self.announced = (now, self.done, eta, None, max(REESTIMATE_AFTER * counted, 20) // 2)
            hint = "; pass --steps for a shorter run" if eta > LONG_FIT_SECONDS else ""
            self.note(f"fit {self.name}: about {_duration(eta)} to go for {self.phase_end - self.done} more steps"
                      f"{self.phase_note} (measured on the last {counted}){hint}")
        elif self.enabled and self.announced is not None:
            self._check_estimate()

    def _check_estimate(self) -> None:
        """At checkpoints after the announcement (half `REESTIMATE_AFTER` times as many steps as it was measured on,
        then twice as many each time): from the second on, the speed of the steps since the previous one (so that
        the steps the announcement measured do not count), and if at that speed the phase would end more than
        `REESTIMATE_FACTOR` times later or sooner than announced, the estimate again (once a phase)."""
        when, step, eta, last, next_check = self.announced
        since = self.done - step
        if since < next_check or self.done == self.phase_end:
            return
        t = time.perf_counter()
        self.announced = (when, step, eta, (t, self.done), 2 * next_check)
        if last is None:  # the first checkpoint starts the window of steps the next one measures
            return
        rate = (t - last[0]) / (self.done - last[1])
        to_go = rate * (self.phase_end - self.done)
        ratio = (t - when + to_go) / max(eta, 1e-9)
        if ratio > REESTIMATE_FACTOR or ratio < 1 / REESTIMATE_FACTOR:
            self.announced = None
            self.note(f"fit {self.name}: about {_duration(to_go)} to go for {self.phase_end - self.done} more steps"
                      f"{self.phase_note}, measured again on the last {self.done - last[1]}: the steps run "
                      f"{max(ratio, 1 / ratio):.1f}x {'slower' if ratio > 1 else 'faster'} than the estimate "
                      f"announced {since} steps ago")

    def note(self, message: str) -> None:
        """Say `message` (an event of the fit, e.g. a rollback) on a line of its own, above the bar on a terminal;
        nothing when progress is off."""
        if self.terminal:
            self.bar.console.print(message, markup=False, highlight=False)
        elif self.enabled:
            print(message, file=sys.stderr, flush=True)

    def show(self, record: dict, total: int) -> None:
        if self.terminal:
            self.bar.update(self.task, loss=f"{record['loss']:.4g}", phase=record["phase"])
        elif self.enabled and (time.perf_counter() - self.last_line > 30 or record["step"] == total):
            self.last_line = time.perf_counter()
            print(f"fit {self.name}: step {record['step']}/{total} ({record['phase']}) loss {record['loss']:.4g}, "
                  f"{time.perf_counter() - self.t0:.0f} s, about {self._eta():.0f} s to go"
                  f"{' in the phase' if self.phase_end < self.total else ''}", file=sys.stderr,
                  flush=True)


def _duration(seconds: float) -> str:
    """`seconds` as "40 s", "12 min" or "2.5 h"."""
    if seconds < 90:
        return f"{seconds:.0f} s"
    return f"{seconds / 60:.0f} min" if seconds < 5400 else f"{seconds / 3600:.1f} h"
