"""Two-phase training of `neumat.models.neural_appearance.NeuralAppearance` (Zeltner et al. 2024, Sec. 5).

Phase 1 (encoder): surface parameters k(x) of the source (`source.sampling_features`) are encoded to z and
decoded to f, end to end, on point targets f(wi, wo | x) (no footprint): wi, wo cosine-weighted (or, with
directions="rusinkiewicz", uniform in half and difference angles as the paper), x uniform.
Then `model.bake(source)` writes the encoder's latents into every texel of every pyramid level (with
encoder_steps = 0 there is no encoder phase and no bake: the latents are optimised from their random
initialisation, the paper's "direct optimisation" ablation).
Phase 2 (latents): the pyramid texels are optimised directly, with the decoders, on filtered targets
f(wi, wo | x, Sigma) for the footprints of `neumat.fit.footprint_queries` (fine levels drawn more often, as the
paper's exponentially distributed filter footprints).
Optionally (blur_degrees > 0) the targets of the first steps are directionally blurred, a cone around wo that
shrinks to nothing, so narrow peaks are learned broad first (Sec. 5, `neumat.fit.directional_blur`).

Every step also trains the sampling decoder on the same queries (or, with sampler_batch="separate", on a second
batch drawn the same way, as the paper): directions drawn from its current proxy are
scored against the model's current BRDF (no gradient) by the KL divergence, with the latent detached, so the
sampler does not disturb the BRDF (`neumat.models.proxy_sampler.proxy_kl_loss`). BRDF loss: "log_cos", the
paper's L1 in log space. Adam; the learning rate halves at 50% and 75% of each phase.

With `Config.albedo` every step also fits the decoder's albedo output with an L2 loss against one-sample
estimates of the source's directional albedo at the same (x, wo) (and footprint): f(w', wo | x) cos / p(w')
with w' from an even mixture of the source's own sampler given wo and the cosine density, or pi f(w', wo | x) for
a cosine-distributed w' when the source cannot sample (Sec. 6.4; unbiased, so the L2 optimum is the albedo).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace

import torch

from ..core.checks import check_int
from ..core.errors import InputError
from ..core.query import Query
from ..warp.hemisphere import sample_cosine_hemisphere
from ..warp.uniform import uniform
from .adam_steps import adam_steps
from .directional_blur import blur_angle, blurred_eval
from .footprint_queries import footprint_queries
from .losses import LogCosLoss
from .query_samplers import QUERY_SAMPLERS


@dataclass
class NeuralAppearanceFit:
    """history: {"phase", "step", "brdf loss", "sampler loss"[, "albedo loss"]} every `log_every` steps; seconds
    per phase."""

    history: list[dict]
    seconds: dict


def fit_neural_appearance(model, source, encoder_steps: int = 2000, latent_steps: int = 2000,
                          batch: int = 4096, lr: float = 3e-3, seed: int = 0, log_every: int = 100,
                          progress: bool = True, directions: str = "cosine", blur_degrees: float = 0.0,
                          blur_samples: int = 4, blur_until: float = 0.5,
                          sampler_batch: str = "shared") -> NeuralAppearanceFit:
    """Train `model` (a NeuralAppearance) on the spatially varying `source` in place (module docstring).

    directions: "cosine" (cosine-weighted wi and wo) or "rusinkiewicz" (uniform half and difference angles, the
    paper's; footprints of the latent phase are kept). blur_degrees > 0: directionally blurred targets, a cone of
    that half-angle around wo at the first step shrinking to 0 at blur_until of all steps, blur_samples directions
    each (`neumat.fit.directional_blur`). sampler_batch: "shared" (the sampler's KL on the BRDF's queries) or
    "separate" (on a second batch drawn the same way, as the paper)."""
    from ..models.neural_appearance import NeuralAppearance
    from ..models.proxy_sampler import proxy_kl_loss

    if not isinstance(model, NeuralAppearance):
        raise InputError(f"fit_neural_appearance: expected a NeuralAppearance model, got {type(model).__name__}")
    if not getattr(source, "spatially_varying", False) or not callable(getattr(source, "sampling_features", None)):
        raise InputError(f"fit_neural_appearance: the source {type(source).__name__} must be spatially varying and "
                         "give its surface parameters through sampling_features(q) (e.g. an SVBRDF)")
    if int(source.sampling_feature_dim) != model.cfg.surface_features:
        raise InputError(f"fit_neural_appearance: the source gives {source.sampling_feature_dim} surface parameters, "
                         f"the model's encoder reads {model.cfg.surface_features} (Config.surface_features)")
    for name, v in (("encoder_steps", encoder_steps), ("latent_steps", latent_steps), ("batch", batch),
                    ("log_every", log_every)):
        check_int(v, f"fit_neural_appearance {name}", 0 if name.endswith("steps") else 1)
    if not lr > 0:
        raise InputError(f"fit_neural_appearance lr: expected > 0, got {lr!r}")
    if directions not in ("cosine", "rusinkiewicz"):
        raise InputError(f"fit_neural_appearance directions: expected 'cosine' or 'rusinkiewicz', got {directions!r}")
    if not (0 <= blur_degrees <= 90 and 0 < blur_until <= 1):
        raise InputError(f"fit_neural_appearance: blur_degrees must lie in [0, 90] and blur_until in (0, 1], got "
                         f"{blur_degrees!r}, {blur_until!r}")
    check_int(blur_samples, "fit_neural_appearance blur_samples", 1)
    if sampler_batch not in ("shared", "separate"):
        raise InputError(f"fit_neural_appearance sampler_batch: expected 'shared' or 'separate', got {sampler_batch!r}")
    gen = torch.Generator().manual_seed(seed)
    brdf_loss = LogCosLoss()
    draw_filtered = footprint_queries(source)
    draw_directions = QUERY_SAMPLERS.get(directions)(source, model)
    total_steps, done = encoder_steps + latent_steps, [0]

    def target_of(q: Query) -> torch.Tensor:
        """The source's value, directionally blurred early in training (blur_degrees > 0)."""
        angle = blur_angle(done[0], total_steps, blur_degrees, blur_until)
        done[0] += 1
        with torch.no_grad():
            return blurred_eval(source, q, angle, blur_samples, gen)
    history, seconds = [], {}
    model.train()

    albedo = model.cfg.albedo
    names = ("brdf loss", "sampler loss") + (("albedo loss",) if albedo else ())

    def phase(name: str, steps: int, params, step_fn) -> None:
        if steps == 0:
            return
        start = time.perf_counter()
        records = adam_steps(params, steps, lr, step_fn, names, f"neural appearance: {name}", log_every, progress)
        history.extend({"phase": name, **r} for r in records)
        seconds[name] = time.perf_counter() - start

    def albedo_estimate(q: Query) -> torch.Tensor:
        """One-sample estimates (N, 3) of the source's albedo at q's x and wo: f(w', wo) cos(theta') / p(w'), w'
        from an even mixture of the source's sampler given wo and the cosine density (defensive: the estimate stays
        below 2 pi f even where the sampler misses f), or cosine-distributed when the source cannot sample."""
        u = uniform(len(q), 2, gen, "cpu")
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

    def losses_at(draw):
        """BRDF (and albedo) losses on a batch from draw() -> (q, z); the sampler's KL on the same batch or on a
        second one (sampler_batch)."""
        q, z = draw()
        u = uniform(batch, 2, gen, "cpu")
        sq, sz = draw() if sampler_batch == "separate" else (q, z)
        sz = sz.detach()
        out = model.decode_outputs(z, q)
        lobes = model.sampler.lobes(sq.wi, sz)
        kl = proxy_kl_loss(lobes, sq.wi, u, lambda wo: model.decode(sz, sq.with_wo(wo)), model.name)
        losses = (brdf_loss(out[:, :3], target_of(q), q), kl)
        if albedo:
            losses += (((out[:, 3:] - albedo_estimate(q)) ** 2).mean(),)
        return losses

    def encoder_batch():
        q = draw_directions(batch, gen, "cpu")
        with torch.no_grad():
            k = source.sampling_features(q)
        return q, model.encode(k)

    def latent_batch():
        q = draw_filtered(batch, gen, "cpu")
        if directions != "cosine":
            d = draw_directions(batch, gen, "cpu")
            q = replace(q, wi=d.wi, wo=d.wo)
        return q, model.spatial_latent(q)

    def encoder_step():
        return losses_at(encoder_batch)

    def latent_step():
        return losses_at(latent_batch)

    decoders = [p for n, p in model.named_parameters() if not n.startswith(("spatial.", "encoder."))]
    phase("encoder", encoder_steps, decoders + list(model.encoder.parameters()), encoder_step)
    if encoder_steps:
        model.bake(source)
    phase("latents", latent_steps, decoders + list(model.spatial.parameters()), latent_step)
    model.eval()
    return NeuralAppearanceFit(history, seconds)
