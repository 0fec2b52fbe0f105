"""Tripleplane baseline (Xu et al. 2024), as adapted by Timonen et al. 2025 (Sec. 5, Eq. 5).

    log f = MLP(T(D, w_d), T(H, w_h), T(S, uv, Sigma))

The same disk-polar angular textures and anisotropically filtered latent pyramid as the gated model
(`neumat.methods.latent_mlp.multiscale`, of which this is a configuration), but the three latents are concatenated
(no gating), without radial warps and without a shading frame. Defaults aim at the paper's Table 5 budget
(H + D = 65.5 kB, MLP ~4 kB in fp32): 16-channel 16 x 32 angular textures, an MLP 40 -> 16 -> 16 -> 3.
"""
from __future__ import annotations

from dataclasses import dataclass

from neumat.methods.latent_mlp import multiscale


@dataclass
class Config(multiscale.Config):
    """Tripleplane hyper-parameters (fields as `neumat.methods.latent_mlp.multiscale.Config`, other defaults)."""

    half_channels: int = 16
    diff_channels: int = 16
    angular_phi: int = 32
    hidden_layers: int = 2
    shading_frame: bool = False
    gating: bool = False
    radial_warps: bool = False


class TriplePlane(multiscale.MultiScale):
    """Concatenated half / difference / spatial latents decoded by an MLP (see module docstring)."""

    name = "tripleplane"
    paper = "triple-plane latent texture: baseline of the multi-scale gated model (Timonen et al. 2025)"
    source_kinds = ("svbrdf",)
    Config = Config
