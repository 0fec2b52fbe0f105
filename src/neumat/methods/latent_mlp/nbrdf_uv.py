"""uv-conditioned NBRDF: the NBRDF input (Rusinkiewicz half and difference vectors, Sztrajman et al. 2021)
with the filtered spatial latent of the multi-scale models concatenated, log f = MLP(z_s, h, d).

A configuration of `neumat.methods.latent_mlp.neumip` (directions "rusinkiewicz"); SiLU and exponential output as the
common codebase of Timonen et al. 2025. Defaults: 2403 FLOPs (gated: 2484). The naive-MLP counterpart on
(z_s, wi, wo) is `neumip` itself.
"""
from __future__ import annotations

from dataclasses import dataclass

from neumat.methods.latent_mlp import neumip


@dataclass
class Config(neumip.Config):
    """Fields as `neumat.methods.latent_mlp.neumip.Config`, with Rusinkiewicz direction inputs."""

    directions: str = "rusinkiewicz"


class NBRDFUV(neumip.NeuMIP):
    """exp(MLP([z_s, h, d])) (see module docstring)."""

    name = "nbrdf-uv"
    paper = "NBRDF with a latent texture: baseline of the multi-scale gated model (Timonen et al. 2025)"
    source_kinds = ("svbrdf",)
    Config = Config
