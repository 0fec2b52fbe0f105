"""Latent textures decoded by small MLPs: the multi-scale gated model (Timonen et al. 2025) and its baselines
(tripleplane, NeuMIP and its offset / frame variants, nbrdf-uv, ggx-mipmap), all trained with its recipe (the
paper trains every model with the same data, loss and optimiser); notes in NOTES.md."""
from neumat.fit.method import Method, register_method
from neumat.fit.preset import Preset
from neumat.methods.latent_mlp import train
from neumat.methods.latent_mlp.drjit import translate as drjit_translate
from neumat.methods.latent_mlp.drjit import translate_ggx_mipmap, translate_neumip
from neumat.methods.latent_mlp.ggx_mipmap import GGXMipmap
from neumat.methods.latent_mlp.glsl import export_latent_mlp
from neumat.methods.latent_mlp.glsl_multiscale import export_multiscale
from neumat.methods.latent_mlp.multiscale import MultiScale
from neumat.methods.latent_mlp.nbrdf_uv import NBRDFUV
from neumat.methods.latent_mlp.neumip import NeuMIP
from neumat.methods.latent_mlp.neumip_frame import NeuMIPFrame
from neumat.methods.latent_mlp.neumip_offset import NeuMIPOffset
from neumat.methods.latent_mlp.tripleplane import TriplePlane

#: "recommended": the paper's model sized to the device, trained with `relative_l2_robust` (Eq. 10 up to relative
#: residual 10, a log tail beyond) instead of Eq. 10 and the gradient's global norm clipped at 1 (the typical norm
#: is 0.5-3; one step's norm of ~900 stalled Adam); on the CPU recipe (1000 steps, 0.2 % of the paper's) at
#: learning rate 1e-2 instead of the paper's 3e-3, which every model fits better in so few steps; "paper" and
#: "cpu" keep Eq. 10 (`relative_l2_mix`) unclipped at 3e-3.
#: Evidence: benchmarks/studies/multiscale/results/polished_metal_stability.md (last section), selection_free.md
#: and NOTES.md's decision table
PRESETS = {"recommended": Preset(
    "the paper's model, sized to the device, with the robust loss (Eq. 10 up to relative residual 10, a log tail "
    "beyond) and gradients clipped at norm 1 (no blow-up on polished metal or stall after a loss spike); on a CPU "
    "at learning rate 1e-2 (mean FLIP about a quarter lower than at the paper's 3e-3 for every model at the CPU "
    "recipe's 1000 steps)",
    overrides={"recipe.loss": "relative_l2_robust", "recipe.grad_clip": 1.0},
    by_recipe={"cpu": {"recipe.lr": 1e-2}})}

#: when to choose each model, from issue 55's selection-free protocol (random 64^2 crops, the default recipe;
#: benchmarks/studies/multiscale/results/selection_free.md), as `neumat list` shows it
MEASURED = {
    "multiscale": "the default for texture sets: mean FLIP over 9 scales below tripleplane's on 44 of 48 random "
                  "shared-set crops x seeds (median ratio 0.96) and the best of all latent-texture models; "
                  "tripleplane ahead on a few Wood092 crops (up to 1.10x) and sub-texel scratches and brushed "
                  "grooves (1.07-1.16x) at 1000 steps",
    "tripleplane": "second to the gated model on random shared-set crops (ahead on 4 of 48, up to 1.10x); ahead on "
                   "sub-texel scratches and brushed grooves at the CPU recipe's 1000 steps",
    "neumip-frame": "third on random shared-set crops (median 1.06x tripleplane's FLIP); on a near-mirror "
                    "(alpha 0.008) 1.9x at 1000 steps, below it at 3000 (--steps 3000)",
}

#: models with a Dr.Jit runtime translator (`neumat.export.drjit`)
DRJIT = {"multiscale": drjit_translate, "tripleplane": drjit_translate, "neumip": translate_neumip,
         "neumip-offset": translate_neumip, "neumip-frame": translate_neumip, "nbrdf-uv": translate_neumip,
         "ggx-mipmap": translate_ggx_mipmap}

for name, model, glsl, small in (
        ("multiscale", MultiScale, export_multiscale, dict(spatial_size=8)),
        ("tripleplane", TriplePlane, export_multiscale, dict(spatial_size=8)),
        ("neumip", NeuMIP, export_latent_mlp, dict(spatial_size=8)),
        ("neumip-offset", NeuMIPOffset, export_latent_mlp, dict(spatial_size=8)),
        ("neumip-frame", NeuMIPFrame, export_latent_mlp, dict(spatial_channels=4, spatial_size=8)),
        ("nbrdf-uv", NBRDFUV, export_latent_mlp, dict(spatial_size=8)),
        ("ggx-mipmap", GGXMipmap, None, dict(spatial_size=8))):
    register_method(Method(name, model, {"paper": train.RECIPE, "cpu": train.CPU_RECIPE}, options=train.Options,
                           phases=train.phases, config_for_source=train.config_for_source, glsl=glsl, small=small,
                           drjit=DRJIT.get(name), presets=PRESETS, measured=MEASURED.get(name, "")))
