"""NeuMIP with its neural offset module ("neumip-offset"): the NeuMIP baseline as Timonen et al. 2025 (Sec. 5.2,
Table 5) run it, "We implement their 'offset module'".

    log f = MLP(z_s(uv + h wo.xy / wo.z), wi, wo),   h = MLP_o(z_o(uv), wo)

A configuration of `neumat.methods.latent_mlp.neumip` (Config.offset on; the module and its defaults are described
there): 5 offset channels and MLP_o 8 -> 6 -> 1 beside the plain model's 8 channels and MLP 14 -> 20 x 3 -> 3, i.e.
MLPs of 5.06 kB in fp32 and 2465 FLOPs (gated: 2484; 1442 counted as the paper counts, its NeuMIP 1633).
"""
from __future__ import annotations

from dataclasses import dataclass

from neumat.methods.latent_mlp import neumip


@dataclass
class Config(neumip.Config):
    """Fields as `neumat.methods.latent_mlp.neumip.Config`, with the neural offset module on."""

    offset: bool = True


class NeuMIPOffset(neumip.NeuMIP):
    """Latent pyramid looked up at a learned parallax offset + MLP (see module docstring)."""

    name = "neumip-offset"
    paper = "NeuMIP with its neural offset module (Kuznetsov et al. 2021): baseline of the multi-scale model " \
            "(Timonen et al. 2025)"
    source_kinds = ("svbrdf",)
    Config = Config
