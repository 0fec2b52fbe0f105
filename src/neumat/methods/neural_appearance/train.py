"""Training recipe of `neumat.methods.neural_appearance.model.NeuralAppearance` (Zeltner et al. 2024, Sec. 5): two
phases through the one trainer (`neumat.fit.trainer.fit`).

Details (schedule, options, measurements): src/neumat/methods/neural_appearance/NOTES.md,
section `neumat.methods.neural_appearance.train`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Literal

import torch
from torch import nn

from neumat.core.config import bounded, config_to_dict
from neumat.core.errors import InputError
from neumat.core.query import Query
from neumat.methods.latent_mlp.spatial_latent import fused_adam
from neumat.methods.neural_appearance.directional_blur import blur_angle, blurred_eval
from neumat.fit.footprint_queries import FootprintOptions, footprint_queries, with_target_samples
from neumat.fit.phase import FitContext, Phase, loss_module, query_draw
from neumat.methods.neural_appearance.proxy_train import proxy_kl_loss
from neumat.models.half_precision import snap_to_half_, with_half_parameters
from neumat.warp.uniform import uniform
from neumat.fit.recipe import Recipe, latent_size_for_source
from neumat.warp.hemisphere import sample_cosine_hemisphere



@dataclass
class Options(FootprintOptions):
    """NeuralAppearance's recipe options (module docstring); fine_bias and elongation_std shape the latents
    phase's footprints."""

    blur_degrees: float = bounded(0.0, ge=0, le=90)
    """Initial half-angle of the directional blur of the targets (0: no blur)."""
    blur_samples: int = bounded(4, ge=1)
    """Directions averaged per blurred target."""
    blur_until: float = bounded(0.5, gt=0, le=1)
    """Fraction of all steps (both phases) at which the blur has shrunk to nothing."""
    sampler_batch: Literal["shared", "separate"] = "shared"
    """The sampling decoder trains on the BRDF's batch ("shared") or on a second one drawn the same way (the paper)."""
    half_finish: float = bounded(0.1, ge=0, le=1)
    """Last fraction of the latents phase trained half-aware, ending on fp16-exact parameters (0: FP32 throughout)."""
    encoder_lr_scale: float = bounded(1.0, gt=0)
    """Factor on the recipe's learning rate in the encoder phase (the `recommended` preset on a CPU: 0.3, the
    encoder at 3e-3 and the latents at 1e-2; at 1e-2 the encoder phase killed the network on Metal027)."""


RECIPE = Recipe(steps=4000, batch_size=4096, lr=3e-3, schedule="halves", loss="log_cos", phase_split=(0.5, 0.5),
                log_every=100, options=config_to_dict(Options()))

#: RECIPE already fits the CPU budget (module docstring)
CPU_RECIPE = RECIPE

#: the phases, in order
PHASES = ("encoder", "latents")


def directions_of(ctx: FitContext) -> str:
    """The query sampler of the directions: the fit's override, else recipe.queries."""
    return ctx.queries if isinstance(ctx.queries, str) else ctx.recipe.queries


def config_for_source(source, options: dict | None = None) -> dict:
    """NeuralAppearance Config fields that follow from the source: spatial_size = the texture's resolution (the
    largest power of two not above its smaller side; the paper's), surface_features = the number of surface
    parameters the source gives (`source.sampling_feature_dim`, what the encoder reads). A field the source
    cannot tell is left out (the Config default applies); explicit settings override these."""
    config = {}
    size = latent_size_for_source(source)
    if size is not None:
        config["spatial_size"] = size
    if getattr(source, "sampling_feature_dim", None) is not None:
        config["surface_features"] = int(source.sampling_feature_dim)
    return config


def _check_queries(ctx: FitContext) -> None:
    if directions_of(ctx) not in ("cosine", "rusinkiewicz"):
        raise InputError(f"neural-appearance recipe queries: expected 'cosine' or 'rusinkiewicz', got "
                         f"{directions_of(ctx)!r}")


def _check(model, source) -> None:
    from neumat.methods.neural_appearance.model import NeuralAppearance

    if not isinstance(model, NeuralAppearance):
        raise InputError(f"neural-appearance fit: expected a NeuralAppearance model, got {type(model).__name__}")
    if not getattr(source, "spatially_varying", False) or not callable(getattr(source, "sampling_features", None)):
        raise InputError(f"neural-appearance fit: the source {type(source).__name__} must be spatially varying and "
                         "give its surface parameters through sampling_features(q) (e.g. an SVBRDF)")
    if int(source.sampling_feature_dim) != model.cfg.surface_features:
        raise InputError(f"neural-appearance fit: the source gives {source.sampling_feature_dim} surface parameters, "
                         f"the model's encoder reads {model.cfg.surface_features} (Config.surface_features; "
                         "config_for_source(source) sets it)")


def phases(ctx: FitContext) -> list[Phase]:
    model, source, dev, gen, batch = ctx.model, ctx.source, ctx.device, ctx.generator, ctx.recipe.batch_size
    _check(model, source)
    _check_queries(ctx)
    o = ctx.opts
    encoder_steps, latent_steps = ctx.split(PHASES)
    total_steps = encoder_steps + latent_steps
    brdf_loss = loss_module(ctx)
    # footprints in uv as before (the texel-relative range is the multi-scale paper's protocol, issue 28)
    draw_filtered = footprint_queries(source, texel_relative=False, fine_bias=o.fine_bias,
                                      elongation_std=o.elongation_std)
    draw_directions = query_draw(ctx)
    targets = with_target_samples(source, o.target_samples)  # the BRDF targets' footprint samples
    albedo = model.cfg.albedo

    def target_of(q: Query, step: int) -> torch.Tensor:
        """The source's value, directionally blurred early in training (blur_degrees > 0); step counts over
        both phases."""
        angle = blur_angle(step, total_steps, o.blur_degrees, o.blur_until)
        with torch.no_grad():
            return blurred_eval(targets, q, angle, o.blur_samples, gen)

    def albedo_estimate(q: Query) -> torch.Tensor:
        """One-sample estimates (N, 3) of the source's albedo at q's x and wo: f(w', wo) cos(theta') / p(w'), w'
        from an even mixture of the source's sampler given wo and the cosine density (defensive: the estimate stays
        below 2 pi f even where the sampler misses f), or cosine-distributed when the source cannot sample."""
        u = uniform(len(q), 2, gen, dev)
        with torch.no_grad():
            if not getattr(source, "can_sample", False):
                return math.pi * source.eval(replace(q, wi=sample_cosine_hemisphere(u)))
            cosine = u[:, 0] < 0.5
            v = torch.stack([torch.where(cosine, 2 * u[:, 0], 2 * u[:, 0] - 1).clamp(max=1 - 1e-7), u[:, 1]], -1)
            given_wo = replace(q, wi=q.wo, wo=None)
            w = torch.where(cosine.unsqueeze(-1), sample_cosine_hemisphere(v), source.sample_direction(given_wo, v)[0])
            w = torch.where((w[:, 2] > 0).unsqueeze(-1), w, w.new_tensor([0.0, 0.0, 1.0]))  # failed samples
            p = 0.5 * source.pdf(given_wo.with_wo(w)) + 0.5 * w[:, 2] / math.pi
            return source.eval(replace(q, wi=w)) * (w[:, 2] / p).unsqueeze(-1)

    def losses_at(draw, step: int) -> dict[str, torch.Tensor]:
        """BRDF (and albedo) losses on a batch from draw() -> (q, z); the sampler's KL on the same batch or on a
        second one (sampler_batch). `step`: the fit's step (over both phases), for the blur schedule."""
        q, z = draw()
        u = uniform(batch, 2, gen, dev)
        sq, sz = draw() if o.sampler_batch == "separate" else (q, z)
        sz = sz.detach()
        out = model.decode_outputs(z, q)
        lobes = model.sampler.lobes(sq.wi, sz)
        kl = proxy_kl_loss(lobes, sq.wi, u, lambda wo: model.decode(sz, sq.with_wo(wo)), model.name)
        losses = {"brdf loss": brdf_loss(out[:, :3], target_of(q, step), q), "sampler loss": kl}
        if albedo:
            losses["albedo loss"] = ((out[:, 3:] - albedo_estimate(q)) ** 2).mean()
        return losses

    def encoder_batch():
        q = draw_directions(batch, gen, dev)
        with torch.no_grad():
            k = source.sampling_features(q)
        return q, model.encode(k)

    half_from = latent_steps - int(round(o.half_finish * latent_steps))  # first half-aware latents step

    def latent_losses(step: int) -> dict[str, torch.Tensor]:
        """The latents phase's losses at its step `step`; half-aware from half_from on (module docstring)."""
        if step < half_from:
            return losses_at(latent_batch, encoder_steps + step)
        return with_half_parameters(model, lambda: losses_at(latent_batch, encoder_steps + step))

    def latent_batch():
        q = draw_filtered(batch, gen, dev)
        if directions_of(ctx) != "cosine":
            d = draw_directions(batch, gen, dev)
            q = replace(q, wi=d.wi, wo=d.wo)
        return q, model.spatial_latent(q)

    decoders = [p for n, p in model.named_parameters() if not n.startswith(("spatial.", "encoder."))]
    # checkpointed with the fit: the loss's state (if any) and the source's own generator (footprint samples)
    stateful = [brdf_loss] if isinstance(brdf_loss, nn.Module) else []

    def encoder_optimizer(params, lr, betas, eps):
        """Adam at encoder_lr_scale times the scheduled rate (the trainer scales each group by its "lr_scale")."""
        return torch.optim.Adam([{"params": params, "lr_scale": o.encoder_lr_scale}], lr=lr * o.encoder_lr_scale,
                                betas=betas, eps=eps)

    return [Phase("encoder", encoder_steps, lambda step: losses_at(encoder_batch, step),
                  decoders + list(model.encoder.parameters()), after=lambda: model.bake(source), stateful=stateful,
                  optimizer=encoder_optimizer),
            Phase("latents", latent_steps, latent_losses, decoders + list(model.spatial.parameters()),
                  after=(lambda: snap_to_half_(model)) if half_from < latent_steps else None, optimizer=fused_adam)]
