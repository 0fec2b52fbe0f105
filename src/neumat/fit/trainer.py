"""Fit any learned model to any source Material with online targets.

Every step draws `batch_size` queries from the recipe's query sampler, evaluates the source on them
without gradient (targets), evaluates the model, and takes one Adam step on the recipe's loss, with the
learning rate of the recipe's schedule. Optional: EMA of the parameters (the EMA copy becomes the fitted
model), gradient-norm clipping, checkpoints (model, optimiser, EMA, loss state, step, history, random
number generator states) from which `resume=True` continues bit for bit as if never interrupted.

Models may define `on_step(step, total_steps)` (annealing, freezing); it is called before every step on
the model and on its EMA copy. They may also define `init_from_targets(target (N, C))`, called once before
the first step of a fresh fit (not on resume) with the source's values on one batch of queries drawn with
seed `recipe.seed + 1`, to start the model at the data's scale, and `optimizer(lr, betas, eps)` to bring
their own optimiser; the schedule's learning rate is multiplied by a param group's "lr_scale" (default 1).
"""
from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Callable

import torch
from torch import nn

from ..core.config import config_to_dict
from ..core.errors import DataFormatError, InputError
from ..core.material import Material
from . import footprint_queries  # noqa: F401  (registers the "footprint" query sampler)
from .ema import EMA
from .losses import LOSSES
from .query_samplers import QUERY_SAMPLERS
from .recipe import Recipe, check_recipe, learning_rate, recipe_for


@dataclass
class FitResult:
    """model: the fitted model (the EMA weights when the recipe uses an EMA), in eval mode.
    history: one record {"step", "loss", "lr", "seconds"} per `log_every` steps (loss averaged over them).
    seconds: training time (summed over resumed runs). steps: steps taken in total."""

    model: nn.Module
    history: list[dict]
    seconds: float
    steps: int


def _describe(source: Any) -> str:
    return source.describe() if hasattr(source, "describe") else type(source).__name__


def check_source(model: nn.Module, source: Material) -> None:
    """Raise InputError if `source` cannot supervise `model` (no eval, spatial variation or sphere mismatch)."""
    if not callable(getattr(source, "eval", None)) or isinstance(source, (str, Path)):
        raise InputError(f"fit: source must be a Material (with eval(q)), got {type(source).__name__}; "
                         "open files and specs with neumat.catalog.open_material.open_material")
    mname = getattr(model, "name", type(model).__name__)
    if getattr(source, "spatially_varying", False) and not getattr(model, "spatially_varying", False):
        raise InputError(f"fit: source {_describe(source)!r} is spatially varying, but model {mname!r} is a "
                         "plain BRDF (give it a neural texture / latent texture to fit spatial variation)")
    if getattr(source, "full_sphere", False) != getattr(model, "full_sphere", False):
        kind = "spans the whole sphere" if getattr(source, "full_sphere", False) else "is an upper-hemisphere BRDF"
        raise InputError(f"fit: source {_describe(source)!r} {kind}, but model {mname!r} does not match "
                         f"(model full_sphere = {getattr(model, 'full_sphere', False)})")


def fit(model: nn.Module, source: Material, recipe: Recipe | None = None, *, steps: int | None = None,
        device: str | torch.device | None = None, progress: bool = True, checkpoint: str | Path | None = None,
        resume: bool = False, callback: Callable[[dict], None] | None = None, loss: str | nn.Module | None = None,
        queries: str | Callable | None = None) -> FitResult:
    """Fit `model` to `source` and return a FitResult; `model` itself is trained in place (and receives the
    EMA weights at the end when the recipe uses an EMA).

    recipe:     defaults to `recipe_for(model.name)`; `steps` overrides recipe.steps.
    device:     torch device for the model, the queries and the targets; default: the model's.
    checkpoint: file written every `recipe.checkpoint_every` steps and at the end; with `resume=True` an
                existing file is loaded and the fit continues from it (it must have the same recipe).
    callback:   called with every history record, after the checkpoint of that step.
    loss:       a LOSSES name or a loss module, overriding recipe.loss.
    queries:    a QUERY_SAMPLERS name or a `draw(n, generator, device) -> Query`, overriding recipe.queries.
    """
    if not isinstance(model, nn.Module) or not isinstance(model, Material):
        raise InputError(f"fit: model must be a torch nn.Module implementing neumat.Material, "
                         f"got {type(model).__name__}")
    recipe = replace(recipe if recipe is not None else recipe_for(getattr(model, "name", type(model).__name__)))
    if steps is not None:
        recipe.steps = steps
    check_recipe(recipe)
    check_source(model, source)
    if resume and checkpoint is None:
        raise InputError("fit: resume=True needs a checkpoint path")
    dev = torch.device(device) if device is not None else _model_device(model)
    model.to(dev).train()
    loss_fn = LOSSES.get(loss or recipe.loss)() if loss is None or isinstance(loss, str) else loss
    if isinstance(loss_fn, nn.Module):
        loss_fn.to(dev)
    if queries is None or isinstance(queries, str):
        draw = QUERY_SAMPLERS.get(queries or recipe.queries)(source, model)
    else:
        draw = queries
    params = [p for p in model.parameters() if p.requires_grad]
    if not params:
        raise InputError(f"fit: model {getattr(model, 'name', type(model).__name__)!r} has no trainable parameters")
    # a model may bring its own optimiser (e.g. NeuBRDF's row-sparse Adam for codebook logits)
    make_optimizer = getattr(model, "optimizer", None)
    opt = (make_optimizer(recipe.lr, tuple(recipe.betas), recipe.eps) if callable(make_optimizer)
           else torch.optim.Adam(params, lr=recipe.lr, betas=tuple(recipe.betas), eps=recipe.eps))
    resuming = resume and Path(checkpoint).is_file()
    init = getattr(model, "init_from_targets", None)
    if callable(init) and not resuming:
        # a model may set its output scale from the data before the first step (NeuBRDF: see its method)
        q0 = draw(recipe.batch_size, torch.Generator(device=dev).manual_seed(recipe.seed + 1), dev)
        with torch.no_grad():
            init(source.eval(q0).to(dev))
    ema = EMA(model, recipe.ema) if recipe.ema > 0 else None
    gen = torch.Generator(device=dev).manual_seed(recipe.seed)
    state = {"step": 0, "history": [], "seconds": 0.0, "running": torch.zeros((), device=dev)}
    if resuming:
        state = _load_checkpoint(checkpoint, recipe, model, opt, ema, loss_fn, gen)
    total = recipe.steps
    hook = getattr(model, "on_step", None)
    ema_hook = getattr(ema.shadow, "on_step", None) if ema is not None else None
    running = state["running"].to(dev)  # loss summed since the last history record
    t0 = time.perf_counter() - state["seconds"]
    with _Progress(progress, total, state["step"], getattr(model, "name", "model")) as bar:
        for step in range(state["step"], total):
            lr = learning_rate(recipe, step, total)
            for group in opt.param_groups:
                group["lr"] = lr * group.get("lr_scale", 1.0)
            if hook is not None:
                hook(step, total)
                if ema_hook is not None:
                    ema_hook(step, total)
            q = draw(recipe.batch_size, gen, dev)
            with torch.no_grad():
                target = source.eval(q)
            if not bool(torch.isfinite(target).all()):
                raise InputError(f"fit: source {_describe(source)!r} returned non-finite values (NaN or inf) "
                                 f"at step {step}; fix or clamp the source")
            pred = model.eval(q)
            value = loss_fn(pred, target.to(pred.dtype), q)
            opt.zero_grad(set_to_none=True)
            value.backward()
            if recipe.grad_clip > 0:
                _clip_gradients(params, recipe.grad_clip)
            opt.step()
            if ema is not None:
                ema.update(model)
            running += value.detach()
            done = step + 1
            bar.advance()
            if done % recipe.log_every == 0 or done == total:
                n = done - (state["history"][-1]["step"] if state["history"] else 0)
                record = {"step": done, "loss": running.item() / n, "lr": lr, "seconds": time.perf_counter() - t0}
                running.zero_()
                if not math.isfinite(record["loss"]):
                    raise InputError(f"fit: the loss became non-finite by step {done} (learning rate {lr:g} "
                                     "too high?)")
                state["history"].append(record)
                bar.show_loss(record["loss"])
            if checkpoint is not None and (done % recipe.checkpoint_every == 0 or done == total):
                state.update(step=done, seconds=time.perf_counter() - t0, running=running)
                _save_checkpoint(checkpoint, recipe, model, opt, ema, loss_fn, gen, state)
            if callback is not None and state["history"] and state["history"][-1]["step"] == done:
                callback(state["history"][-1])
    seconds = time.perf_counter() - t0
    if ema is not None:
        model.load_state_dict(ema.state_dict())
    model.train(False)
    return FitResult(model=model, history=state["history"], seconds=seconds, steps=total)


def _clip_gradients(params: list[torch.Tensor], max_norm: float) -> None:
    """Scale all gradients (dense or sparse) so that their joint 2-norm is at most `max_norm`."""
    grads = [p.grad.coalesce().values() if p.grad.is_sparse else p.grad for p in params if p.grad is not None]
    total = torch.linalg.vector_norm(torch.stack([torch.linalg.vector_norm(g) for g in grads]))
    scale = (max_norm / (total + 1e-6)).clamp(max=1.0)
    for p in params:
        if p.grad is not None:
            p.grad.mul_(scale)


def _model_device(model: nn.Module) -> torch.device:
    for t in list(model.parameters()) + list(model.buffers()):
        return t.device
    return torch.device("cpu")


def _rng_states(gen: torch.Generator) -> dict:
    states = {"queries": gen.get_state(), "torch": torch.get_rng_state()}
    if torch.cuda.is_available():
        states["cuda"] = torch.cuda.get_rng_state_all()
    return states


def _save_checkpoint(path, recipe, model, opt, ema, loss_fn, gen, state) -> None:
    blob = {"recipe": config_to_dict(recipe), "model": model.state_dict(), "optimizer": opt.state_dict(),
            "ema": ema.state_dict() if ema is not None else None,
            "loss": loss_fn.state_dict() if isinstance(loss_fn, nn.Module) else None,
            "rng": _rng_states(gen), **state}
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    torch.save(blob, tmp)
    os.replace(tmp, path)  # never leave a half-written checkpoint


def _load_checkpoint(path, recipe, model, opt, ema, loss_fn, gen) -> dict:
    try:
        blob = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # noqa: BLE001 - any unreadable file is reported the same way
        raise DataFormatError(f"checkpoint {str(path)!r}: cannot be read ({e})") from None
    saved = dict(blob["recipe"])
    now = config_to_dict(recipe)
    if saved != now:
        diff = sorted(k for k in now if saved.get(k) != now[k])
        raise InputError(f"checkpoint {str(path)!r} was written with a different recipe (fields {', '.join(diff)}); "
                         "resume with the same recipe or start a new checkpoint")
    model.load_state_dict(blob["model"])
    opt.load_state_dict(blob["optimizer"])
    if ema is not None:
        ema.load_state_dict(blob["ema"])
    if isinstance(loss_fn, nn.Module) and blob["loss"] is not None:
        loss_fn.load_state_dict(blob["loss"])
    rng = blob["rng"]
    gen.set_state(rng["queries"])
    torch.set_rng_state(rng["torch"])
    if "cuda" in rng and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(rng["cuda"])
    return {"step": blob["step"], "history": blob["history"], "seconds": blob["seconds"],
            "running": blob["running"]}


class _Progress:
    """A rich progress bar with the live loss, or nothing when `enabled` is false."""

    def __init__(self, enabled: bool, total: int, start: int, name: str) -> None:
        self.enabled = enabled
        if enabled:
            from rich.console import Console
            from rich.progress import (BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn,
                                       TimeRemainingColumn)
            self.bar = Progress(TextColumn(f"fit {name}"), BarColumn(), MofNCompleteColumn(),
                                TextColumn("loss {task.fields[loss]}"), TimeElapsedColumn(), TimeRemainingColumn(),
                                console=Console(stderr=True))
            self.task = self.bar.add_task("fit", total=total, completed=start, loss="-")

    def __enter__(self) -> "_Progress":
        if self.enabled:
            self.bar.__enter__()
        return self

    def __exit__(self, *exc) -> None:
        if self.enabled:
            self.bar.__exit__(*exc)

    def advance(self) -> None:
        if self.enabled:
            self.bar.advance(self.task)

    def show_loss(self, loss: float) -> None:
        if self.enabled:
            self.bar.update(self.task, loss=f"{loss:.4g}")
