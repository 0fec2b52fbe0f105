"""Real-Time Neural Appearance Models (Zeltner et al., ACM TOG 2024): a latent texture read by two small
decoders, one for the BRDF and one for importance sampling.

    f(x, wi, wo) = exp(MLP(z(x), T(z) wi, T(z) wo))                       (Eq. 3)
    p(wo | x, wi) = two-lobe proxy(MLP_s(wi, sg(z(x))))                   (Sec. 4.3, App. A)

z(x): a latent mip pyramid; T: learned shading frames; the sampler a `ProxySampler`. Trained with an
encoder, then baked and fine-tuned (`neumat.methods.neural_appearance.train`).

Details: src/neumat/methods/neural_appearance/NOTES.md, section `neumat.methods.neural_appearance.model`.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F

from neumat.core.checks import check_int
from neumat.core.errors import InputError
from neumat.core.query import Query, Sample
from neumat.methods.latent_mlp import neumip
from neumat.models.btf_table_queries import texel_centre_uv
from neumat.methods.neural_appearance.proxy_sampler import ProxySampler, check_lobe_family, defensive_pdf, draw_sample
from neumat.nn.codebook import float_bits, storage_bytes
from neumat.nn.mlp import MLP
from neumat.nn.preconditioner import unprecondition
from neumat.reflectance.lean import lean_pyramid
from neumat.warp.microfacet_proxy import ProxyLobes


@dataclass
class Config(neumip.Config):
    """Fields of `neumat.methods.latent_mlp.neumip.Config` (latent pyramid and BRDF decoder) with the paper's choices,
    and the encoder and sampler sizes."""

    spatial_size: int = 256
    hidden: int = 32
    hidden_layers: int = 2
    init_from_data: bool = False
    """Its encoder-driven training starts at init_log_value; the data-scale start was measured on the other
    latent-texture models only."""
    shading_frame: bool = True
    frames: int = 2
    spatial_precondition: float = 0.0
    init_std: float = 0.1
    surface_features: int = 8
    """k: surface parameters per point that the encoder reads (an SVBRDF gives 8)."""
    encoder_hidden: int = 32
    """Neurons per hidden layer of the encoder (training only)."""
    encoder_layers: int = 2
    """Hidden layers of the encoder."""
    sampler_hidden: int = 32
    """Neurons per hidden layer of the sampling decoder (paper: 32)."""
    sampler_layers: int = 3
    """Hidden layers of the sampling decoder (paper: 3)."""
    sampler_lobes: str = "anisotropic"
    """The sampler's lobes (`neumat.methods.neural_appearance.proxy_sampler.Config.lobes`): "anisotropic", the paper's
    (elliptical, non-centred GGX and tilted cosine lobe), or "isotropic", its ablation (Sec. 6.3, Fig. 11: a diffuse
    weight and one roughness; centred isotropic GGX, untilted cosine lobe; no GLSL / Slang export)."""
    lean: bool = True
    """`bake` fills coarse levels from LEAN-prefiltered surface parameters (Sec. 5.1; `neumat.reflectance.lean`)
    where the source names its normal and roughness channels (`surface_normal_groups`); else, or when False,
    from box-filtered ones."""
    albedo: bool = False
    """The BRDF decoder also outputs the directional albedo alpha(x, wo) = int f cos(theta_i) dwi as an extra RGB
    triplet (Sec. 6.4), trained with L2 against one-sample estimates; read it with `albedo(q)`."""


class NeuralAppearance(neumip.NeuMIP):
    """Latent pyramid + BRDF decoder with 2 learned frames + neural importance sampler (module docstring)."""

    name = "neural-appearance"
    paper = "Real-Time Neural Appearance Models (Zeltner et al. 2024)"
    source_kinds = ("svbrdf",)
    can_sample = True
    Config = Config

    def __init__(self, config: Config | None = None, **kwargs) -> None:
        super().__init__(config, **kwargs)
        c = self.cfg
        for name in ("surface_features", "encoder_hidden", "encoder_layers", "sampler_hidden", "sampler_layers"):
            check_int(getattr(c, name), f"{self.name}.{name}", 0 if name.endswith("layers") else 1)
        check_lobe_family(c.sampler_lobes, f"{self.name}.sampler_lobes")
        self.encoder = MLP(c.surface_features, c.encoder_hidden, c.encoder_layers, c.spatial_channels, "silu")
        self.sampler = ProxySampler(features=c.spatial_channels, hidden=c.sampler_hidden,
                                    hidden_layers=c.sampler_layers, lobes=c.sampler_lobes)
        self._runtime = False
        self.register_state_dict_post_hook(_without_encoder)
        self.register_load_state_dict_pre_hook(_own_encoder)

    @property
    def is_runtime(self) -> bool:
        """Whether `runtime()` is in effect (model files record it and re-enter it on load)."""
        return self._runtime

    def runtime(self) -> "NeuralAppearance":
        """The shipped form: what `size_bytes` counts, without the encoder (training only; a model file written in
        this mode does not store it, and `encode` then refuses). Returns self."""
        self._runtime = True
        return self

    @property
    def outputs(self) -> int:
        """MLP outputs: log f (3), then log alpha (3) with `Config.albedo`."""
        return 6 if self.cfg.albedo else 3

    def albedo(self, q: Query) -> torch.Tensor:
        """Directional albedo (N, 3) for the viewer direction q.wo at q.uv (footprint / lod as for eval), the
        decoder's extra output (Sec. 6.4); q.wi is a network input the training makes it independent of.
        0 below either horizon. Raises InputError unless the model was built with `albedo=True`."""
        if not self.cfg.albedo:
            raise InputError(f"{self.name}.albedo: the model has no albedo output (build it with albedo=True)")
        q.require("wo", who=f"{self.name}.albedo")
        return self.filtered_outputs(q)[:, 3:]

    # ------------------------------------------------------------------------------ sampling
    def lobes(self, q: Query) -> ProxyLobes:
        """Proxy parameters at q (uv, footprint / lod as for eval) for q.wi."""
        return self.sampler.lobes(q.wi, self.sampling_features(q))

    @torch.no_grad()
    def sample(self, q: Query, u: torch.Tensor) -> Sample:
        """Draw wo given q.wi (and q.uv) and u (N, 2) in [0, 1)^2 from the proxy with a defensive cosine share
        (`neumat.methods.neural_appearance.proxy_sampler.DEFENSIVE`); weight = eval cos / pdf."""
        z = self.sampling_features(q)                       # filtered once, for the lobes and the weights
        if self.cfg.level_selection == "roulette":          # the weights use eval's two-level expectation
            return draw_sample(self.sampler.lobes(q.wi, z), q, u, lambda wo: self.eval(q.with_wo(wo)))
        return draw_sample(self.sampler.lobes(q.wi, z), q, u, lambda wo: self.decode(z, q.with_wo(wo)))

    @torch.no_grad()
    def pdf(self, q: Query) -> torch.Tensor:
        """Solid-angle density (N,) of `sample` at q.wo."""
        q.require("wo", who=f"{self.name}.pdf")
        return defensive_pdf(self.lobes(q), q.wi, q.wo, check=False)

    # ------------------------------------------------------------------------------ encoder
    def encode(self, k: torch.Tensor) -> torch.Tensor:
        """Latents z (N, D_s) of surface parameters k (N, K) (training phase 1)."""
        if self._runtime:
            raise InputError(f"{self.name}.encode: a runtime model (`runtime()`, or a model file that `neumat fit` "
                             "wrote) has no encoder; train from a checkpoint or a fresh model")
        if k.shape[-1] != self.cfg.surface_features:
            raise InputError(f"{self.name}.encode: expected {self.cfg.surface_features} surface parameters per "
                             f"point, got shape {tuple(k.shape)}")
        return self.encoder(k.to(self.encoder.linears()[0].weight.dtype))

    @torch.no_grad()
    def bake(self, source) -> None:
        """Fill every pyramid level with the encoder's latents of the source's surface parameters at its texel
        centres (finest level), LEAN-prefiltered (`Config.lean`) or box-filtered for the coarser levels (Sec. 5.1
        step 2)."""
        size = self.cfg.spatial_size
        device = self.spatial.raw[0].device
        uv = texel_centre_uv(size, size, device=device)
        wi = torch.tensor([[0.0, 0.0, 1.0]], device=device).expand(len(uv), 3)
        k = source.sampling_features(Query(wi, uv=uv)).float()
        if k.shape != (len(uv), self.cfg.surface_features):
            raise InputError(f"{self.name}.bake: the source gives surface parameters of shape {tuple(k.shape)}, "
                             f"expected ({len(uv)}, {self.cfg.surface_features})")
        finest = k.t().reshape(-1, size, size)
        groups = list(getattr(source, "surface_normal_groups", ()))
        if self.cfg.lean and groups:
            pyramid = lean_pyramid(finest, groups, len(self.spatial.raw))
        else:
            pyramid = [F.avg_pool2d(finest[None], 1 << level)[0] for level in range(len(self.spatial.raw))]
        for raw, kl in zip(self.spatial.raw, pyramid):
            z = self.encode(kl.reshape(kl.shape[0], -1).t()).t().reshape(raw.shape)
            strength = self.cfg.spatial_precondition
            raw.copy_(unprecondition(z, strength) if strength else z)

    # ------------------------------------------------------------------------------ accounting
    def size_bytes(self, precision: str = "fp16") -> int:
        """Stored for rendering: latent pyramid, BRDF decoder (frames, MLP) and sampler; not the encoder."""
        params = sum(p.numel() for name, p in self.named_parameters() if not name.startswith("encoder."))
        return storage_bytes(params * float_bits(precision))


def _without_encoder(module: NeuralAppearance, state_dict: dict, prefix: str, local_metadata) -> None:
    """State-dict hook: a runtime model's state leaves out the encoder (training only)."""
    if module.is_runtime:
        for key in [k for k in state_dict if k.startswith(prefix + "encoder.")]:
            del state_dict[key]


def _own_encoder(module: NeuralAppearance, state_dict: dict, prefix: str, local_metadata, strict, missing_keys,
                 unexpected_keys, error_msgs) -> None:
    """Load-state-dict pre-hook: a state without the encoder (a runtime model file) keeps the module's own, unused
    encoder, and the module enters runtime mode."""
    if any(k.startswith(prefix + "encoder.") for k in state_dict):
        return
    for key, value in module.encoder.state_dict(prefix=prefix + "encoder.").items():
        state_dict[key] = value
    module._runtime = True
