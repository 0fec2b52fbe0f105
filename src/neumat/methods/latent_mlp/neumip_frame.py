"""NeuMIP with a learned shading frame ("neumip-frame"): the Zeltner et al. 2024 style decoder that Timonen et al.
2025 (Sec. 5.2) use as a baseline: latent pyramid, learned shading frame decoded from the latent, and an MLP on the
concatenated latent and the directions expressed in that frame (no angular tabulation, no gating).

Not the model of Zeltner et al. 2024 itself, which is `neumat.methods.neural_appearance.model` ("neural-appearance": an
encoder, two frames, an importance sampler). Registered as "zeltner" before; such model files still load.

    log f = MLP(z_s, F(z_s) wi, F(z_s) wo)

A configuration of `neumat.methods.latent_mlp.neumip` (shading_frame on). Trained like every model of the paper's
common codebase: textures optimised directly with the preconditioner, no encoder / multi-stage training.
Defaults: 8 latent channels, MLP 14 -> 20 x 3 -> 3 and a linear frame decoder: 2526 FLOPs (gated: 2484).
"""
from __future__ import annotations

from dataclasses import dataclass

from neumat.methods.latent_mlp import neumip


@dataclass
class Config(neumip.Config):
    """Fields as `neumat.methods.latent_mlp.neumip.Config`, with the learned shading frame on."""

    shading_frame: bool = True


class NeuMIPFrame(neumip.NeuMIP):
    """Latent pyramid + learned shading frame + MLP (see module docstring)."""

    name = "neumip-frame"
    paper = ("NeuMIP with a learned shading frame (Zeltner-style): baseline of the multi-scale model "
             "(Timonen et al. 2025)")
    source_kinds = ("svbrdf",)
    Config = Config
