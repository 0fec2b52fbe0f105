"""Training recipe of `neumat.models.neural_appearance.NeuralAppearance` (Zeltner et al. 2024, Sec. 5): two
phases through the one trainer (`neumat.fit.trainer.fit`).

Phase "encoder": surface parameters k(x) of the source (`source.sampling_features`) are encoded to z and
decoded to f, end to end, on point targets f(wi, wo | x) (no footprint): wi, wo cosine-weighted (or, with
recipe queries="rusinkiewicz", uniform in half and difference angles as the paper), x uniform. Trains the
decoders and the encoder. After its last step, `model.bake(source)` writes the encoder's latents into every
texel of every pyramid level (with phase_split (0, 1) there is no encoder phase and no bake: the latents are
optimised from their random initialisation, the paper's "direct optimisation" ablation).
Phase "latents": the pyramid texels are optimised directly, with the decoders, on filtered targets
f(wi, wo | x, Sigma) for the footprints of `neumat.fit.footprint_queries` (fine levels drawn more often, as the
paper's exponentially distributed filter footprints).
The last half_finish of the latents phase's steps (default 10 %) train half-aware (a deviation from the paper,
which trains in FP32 and infers in FP16): every parameter enters the forward rounded as the fp16 exports store it,
with a straight-through gradient, and the phase ends by rounding the parameters in place
(`neumat.models.half_precision`), so the fitted model is exactly what its fp16 export stores
(benchmarks/studies/neural_appearance/results/neural_appearance_timing.md: rounding a model trained in FP32 moves eval by up to 5e-3 and the
pdf by up to 3e-3, relative). half_finish=0 trains in FP32 to the end, as the paper.
Optionally (blur_degrees > 0) the targets of the first steps are directionally blurred, a cone around wo that
shrinks to nothing at blur_until of all steps (counted over both phases), blur_samples directions each, so
narrow peaks are learned broad first (Sec. 5, `neumat.fit.directional_blur`).

Every step also trains the sampling decoder on the same queries (or, with sampler_batch="separate", on a second
batch drawn the same way, as the paper): directions drawn from its current proxy are scored against the model's
current BRDF (no gradient) by the KL divergence, with the latent detached, so the sampler does not disturb the
BRDF (`neumat.fit.proxy_sampler.proxy_kl_loss`). BRDF loss: the recipe's ("log_cos", the paper's L1 in log
space). Adam; the learning rate halves at 50 % and 75 % of each phase ("halves").

With `Config.albedo` every step also fits the decoder's albedo output with an L2 loss against one-sample
estimates of the source's directional albedo at the same (x, wo) (and footprint): f(w', wo | x) cos / p(w')
with w' from an even mixture of the source's own sampler given wo and the cosine density, or pi f(w', wo | x) for
a cosine-distributed w' when the source cannot sample (Sec. 6.4; unbiased, so the L2 optimum is the albedo).

History records carry "brdf loss", "sampler loss" (and "albedo loss"); "loss" is their sum.
`config_for_source(source)` gives the model Config fields that follow from the source (spatial_size,
surface_features).

CPU_RECIPE: RECIPE itself: 2000 steps of 2048 took 45-62 s on one core for 64^2 texture sets
(benchmarks/studies/neural_appearance/results/neural_appearance.md), so RECIPE's 4000 of 4096 take about 4 minutes there.
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
from neumat.fit.directional_blur import blur_angle, blurred_eval
from neumat.fit.footprint_queries import FootprintOptions, footprint_queries
from neumat.fit.phase import FitContext, Phase, loss_module, query_draw
from neumat.fit.proxy_sampler import proxy_kl_loss
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
    from neumat.models.neural_appearance import NeuralAppearance

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
    albedo = model.cfg.albedo

    def target_of(q: Query, step: int) -> torch.Tensor:
        """The source's value, directionally blurred early in training (blur_degrees > 0); step counts over
        both phases."""
        angle = blur_angle(step, total_steps, o.blur_degrees, o.blur_until)
        with torch.no_grad():
            return blurred_eval(source, q, angle, o.blur_samples, gen)

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
    return [Phase("encoder", encoder_steps, lambda step: losses_at(encoder_batch, step),
                  decoders + list(model.encoder.parameters()), after=lambda: model.bake(source), stateful=stateful),
            Phase("latents", latent_steps, latent_losses, decoders + list(model.spatial.parameters()),
                  after=(lambda: snap_to_half_(model)) if half_from < latent_steps else None)]
