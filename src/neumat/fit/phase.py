"""Phases of a fit: what one stretch of the trainer's loop optimises, and how one step computes its losses.

The trainer (`neumat.fit.trainer.fit`) runs a list of phases one after the other in one loop, with one step
counter, one checkpoint and one history. A method (`neumat.fit.method.Method`) may declare
`phases(ctx) -> list[Phase]` for models that train in stages (encoder then latents, appearance then
sampler, dictionary then coding); without it a fit is the single phase `online_phase(ctx)`: online targets
`source.eval(q)` at queries from the recipe's query sampler, the recipe's loss.

A phase with `params` takes an optimiser step on the sum of its losses; a phase without `params` is a
solver phase: its `losses` callable updates the model itself (a dictionary iteration, a projection) and
returns numbers to log.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import torch
from torch import nn

from ..core.errors import InputError
from ..core.material import Material, describe_source
from .losses import LOSSES
from .query_samplers import QUERY_SAMPLERS
from .recipe import Recipe

LossStep = Callable[[int], dict[str, torch.Tensor]]


@dataclass
class Phase:
    """`steps` steps of `losses(step_in_phase) -> {name: scalar tensor}`.

    params:    parameters the optimiser updates in this phase (None: a solver phase, no optimiser), or a
               callable returning them when the phase starts, for parameters that an earlier phase's `after`
               creates (NeuBRDF's dense warm-up replaces the feature grid by a codebook).
    start:     called when the phase begins, also when a resumed fit continues inside it or skips it as done: sets
               model state that neither parameters nor checkpoints hold (NeuBRDF's runtime phase switches the
               model to its 1/4-weight form).
    after:     called once when the phase has run its last step (before that step's checkpoint), e.g. to bake
               latents from the encoder or freeze what the phase trained.
    optimizer: `make(params, lr, betas, eps) -> torch.optim.Optimizer`, default Adam.
    stateful:  modules with state of their own (a loss's running statistics), checkpointed with the fit.
    on_record: called with each history record of this phase before it is stored, checkpointed or shown (it
               may add fields, e.g. a validation loss); at the phase's last step it runs before `after`.
    slow_from: the step of the phase from which its steps cost far more (batches traced online), or None: the
               trainer says so and measures its time estimate again there, so that the estimate stays honest.
    """

    name: str
    steps: int
    losses: LossStep
    params: list[nn.Parameter] | Callable[[], list[nn.Parameter]] | None = None
    start: Callable[[], None] | None = None
    after: Callable[[], None] | None = None
    optimizer: Callable[..., torch.optim.Optimizer] | None = None
    stateful: list[nn.Module] = field(default_factory=list)
    on_record: Callable[[dict], None] | None = None
    slow_from: int | None = None


@dataclass
class FitContext:
    """What a recipe's `phases(ctx)` builds its phases from.

    model, source, recipe: the fit's; device: where queries, targets and the model live; generator: the
    fit's random numbers (checkpointed); resuming: True when the fit continues from a checkpoint (a phase
    builder must then not re-initialise the model from data); loss / queries: overrides of the recipe's
    loss and query-sampler names, or a loss module / a `draw(n, generator, device) -> Query`."""

    model: nn.Module
    source: Any
    recipe: Recipe
    device: torch.device
    generator: torch.Generator
    resuming: bool = False
    loss: str | nn.Module | None = None
    queries: str | Callable | None = None

    @property
    def opts(self) -> Any:
        """The recipe's options, typed and checked (`neumat.fit.recipe.typed_options`)."""
        from .method import typed_options

        return typed_options(model_name(self.model), self.recipe.options)

    def split(self, names: tuple[str, ...]) -> list[int]:
        """The recipe's steps split over phases `names` by Recipe.phase_split (fractions; the last phase takes
        the rounding rest). An empty phase_split with one name gives all steps to it."""
        fractions = tuple(self.recipe.phase_split) or ((1.0,) if len(names) == 1 else ())
        if len(fractions) != len(names):
            raise InputError(f"recipe of {model_name(self.model)!r}: phase_split needs {len(names)} fractions "
                             f"({', '.join(names)}), got {list(fractions)}")
        steps = [int(round(f * self.recipe.steps)) for f in fractions[:-1]]
        return steps + [max(self.recipe.steps - sum(steps), 0)]


def model_name(model: Any) -> str:
    return getattr(model, "name", type(model).__name__)


def check_source(model: nn.Module, source: Material) -> None:
    """Raise InputError if `source` cannot supervise `model` by online targets (no eval, spatial variation
    or sphere mismatch)."""
    if not callable(getattr(source, "eval", None)) or isinstance(source, (str, Path)):
        raise InputError(f"fit: source must be a Material (with eval(q)), got {type(source).__name__}; "
                         "open files and specs with neumat.open_material")
    mname = model_name(model)
    if getattr(source, "spatially_varying", False) and not getattr(model, "spatially_varying", False):
        raise InputError(f"fit: source {describe_source(source)!r} is spatially varying, but model {mname!r} is a "
                         "plain BRDF (give it a neural texture / latent texture to fit spatial variation)")
    if getattr(source, "full_sphere", False) != getattr(model, "full_sphere", False):
        kind = "spans the whole sphere" if getattr(source, "full_sphere", False) else "is an upper-hemisphere BRDF"
        raise InputError(f"fit: source {describe_source(source)!r} {kind}, but model {mname!r} does not match "
                         f"(model full_sphere = {getattr(model, 'full_sphere', False)})")


def loss_module(ctx: FitContext) -> nn.Module:
    """The fit's loss: ctx.loss (a LOSSES name or a module) or the recipe's, on ctx.device."""
    loss = ctx.loss
    fn = LOSSES.get(loss or ctx.recipe.loss)() if loss is None or isinstance(loss, str) else loss
    return fn.to(ctx.device) if isinstance(fn, nn.Module) else fn


def query_draw(ctx: FitContext, name: str | None = None):
    """`draw(n, generator, device) -> Query` of ctx.queries, else `name`, else the recipe's query sampler."""
    if ctx.queries is not None and not isinstance(ctx.queries, str):
        return ctx.queries
    return QUERY_SAMPLERS.get(ctx.queries or name or ctx.recipe.queries)(ctx.source, ctx.model)


def online_targets(ctx: FitContext, q) -> torch.Tensor:
    """The source's values at q without gradient; InputError when they are not finite."""
    with torch.no_grad():
        target = ctx.source.eval(q)
    if not bool(torch.isfinite(target).all()):
        raise InputError(f"fit: source {describe_source(ctx.source)!r} returned non-finite values (NaN or inf); "
                         "fix or clamp the source")
    return target


def online_phase(ctx: FitContext, name: str = "fit", steps: int | None = None,
                 params: list[nn.Parameter] | None = None) -> Phase:
    """Online targets at the recipe's queries, the recipe's loss, all trainable parameters (or `params`), the
    model's own optimiser when it brings one (`model.optimizer(lr, betas, eps)`, e.g. NeuBRDF's row-sparse
    Adam). On a fresh fit, a model's `init_from_targets(target (N, C))` sees the source's values at one batch
    drawn with seed recipe.seed + 1 (its output scale from the data); `observe_targets` sees every batch's."""
    model, recipe, dev = ctx.model, ctx.recipe, ctx.device
    check_source(model, ctx.source)
    loss_fn = loss_module(ctx)
    draw = query_draw(ctx)
    trainable = params if params is not None else [p for p in model.parameters() if p.requires_grad]
    if not trainable:
        raise InputError(f"fit: model {model_name(model)!r} has no trainable parameters")
    if not ctx.resuming:
        q0 = draw(recipe.batch_size, torch.Generator(device=dev).manual_seed(recipe.seed + 1), dev)
        model.init_from_targets(online_targets(ctx, q0).to(dev))

    def losses(step: int) -> dict[str, torch.Tensor]:
        q = draw(recipe.batch_size, ctx.generator, dev)
        target = online_targets(ctx, q)
        model.observe_targets(target)
        pred = model.eval(q)
        return {"loss": loss_fn(pred, target.to(pred.dtype), q)}

    def make(params_, lr, betas, eps):
        own = model.optimizer(lr, betas, eps) if params is None else None
        return own if own is not None else torch.optim.Adam(params_, lr=lr, betas=betas, eps=eps)

    return Phase(name, recipe.steps if steps is None else steps, losses, trainable, optimizer=make,
                 stateful=[loss_fn] if isinstance(loss_fn, nn.Module) else [])
