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

#: models whose CPU recipe drops the frequency preconditioner of the spatial latents (`spatial_precondition` 0
#: instead of the paper's 10): at lr 1e-2 and 1000 steps each fits better without it on the selection-free crops,
#: tuning and held-out pairs; ggx-mipmap fits worse without it (3 of 11 pairs, median 1.10x) and keeps it
#: (selection_free.md, "Learning rate 1e-2 and the texture-set default")
UNPRECONDITIONED_ON_CPU = ("multiscale", "tripleplane", "neumip", "neumip-frame", "neumip-offset", "nbrdf-uv")
#: the CPU recipe's optimiser for these models: Adam's first moment and the weights' EMA on a 1000-step horizon
#: (beta1 0.9, EMA weight 0.02) instead of the paper's 500k-step ones (0.99, 0.005), which lag the weights that the
#: fit's last few hundred steps reach (selection_free.md, "A short-run optimiser")
SHORT_RUN_OPTIMISER_ON_CPU = UNPRECONDITIONED_ON_CPU
SHORT_RUN_OPTIMISER = {"recipe.betas": (0.9, 0.999), "recipe.ema": 0.02}
#: the CPU recipe's budget for these models: 4000 steps on 32-position footprint targets instead of 1000 on the
#: source's 256 (the paper's): the 256-position targets were 85-90 % of a step (0.66 s of a 1K set's step at 2^12
#: queries against 0.20 s at 32), and at 1000 steps they fit no better than 8-position ones (mean FLIP within 6 %);
#: the time goes to steps instead (a 1K set: about 13 min against 11; selection_free.md, "Where the CPU's time goes")
LONG_RUN_ON_CPU = ("multiscale", "tripleplane", "nbrdf-uv")
LONG_RUN = {"recipe.steps": 4000, "option.target_samples": 32}
#: the NeuMIP variants' CPU budget: twice LONG_RUN's steps. They learn a flat metal's specular lobe from Cartesian
#: directions more slowly than the others do in angular textures: at 4000 steps their fits there were still
#: descending and ended up to 1.65x tripleplane's FLIP (issue 55's bound: 1.5x); at 8000 they were lower on every
#: flat-set pair refitted but two of neumip-frame's, 0.65-1.35x tripleplane's default fit but one (1.52x;
#: selection_free.md, "Every latent-texture model over the protocol"). A departure from the paper's one budget for
#: every model; a 64^2 crop's fit takes 2-6 min, a whole 1K set's about 26 (`--set recipe.steps=4000` gives the
#: gated model's budget back)
LONGER_RUN_ON_CPU = ("neumip", "neumip-frame", "neumip-offset")
LONGER_RUN = {**LONG_RUN, "recipe.steps": 2 * LONG_RUN["recipe.steps"]}
#: the CPU recipe's initial scale of the latents for these models: N(0, 0.1^2) instead of N(0, 1) (`init_std`).
#: Without the preconditioner a texel keeps what the fit's queries leave of its initial value, and the CPU budget's
#: queries leave much of it (a whole 1K set: about 16 queries a texel): at std 1 that remainder is noise in every
#: image. Measured better or level (within 2 %) on 37 of 38 (model, source, seed) pairs of the first crops, larger
#: sources and other models (tripleplane on the polished plate at seed 1 1.15x; on held-out Fabric02 crops the gated
#: model 0.98-1.09x), most where the gated model trailed tripleplane (a Metal027 crop 0.59x, a 256^2 Leather05 crop
#: 0.46x, whole 1K sets 0.71-0.76x its FLIP at std 1; selection_free.md, "The latents' initial scale")
SMALL_INIT_ON_CPU = UNPRECONDITIONED_ON_CPU
SMALL_INIT = {"model.init_std": 0.1}
#: the CPU recipe's schedule for these models: the rate halved at 50 % and again at 75 % of the steps ("halves")
#: instead of constant. At 1e-2 to the end neumip-frame's weights kept moving (15-30 % in FLIP from one thousand
#: steps to the next), and one seed's fit of a Wood092 crop ended at 1.52x tripleplane's FLIP (issue 55's bound:
#: 1.5x); halved, 1.16x. Lower than the constant rate on 42 of the 58 (crop, seed) pairs measured at 8000 steps
#: (median 0.96x, 0.77-1.13x: higher on the flat metals at seed 1), 25 of 30 of them held out (median 0.96x, at
#: most 1.03x); every pair 0.59-1.28x tripleplane's default fit (constant: 0.65-1.52x; selection_free.md, first
#: section). Measured for neumip-frame only: the other NeuMIP variants were within the bound at the constant rate
HALVED_RATE_ON_CPU = ("neumip-frame",)
HALVED_RATE = {"recipe.schedule": "halves"}
#: the CPU recipe's departures from the paper's above: the models each applies to, its overrides, and how the
#: recommended preset's description names it
CPU_CHANGES = ((UNPRECONDITIONED_ON_CPU, {"model.spatial_precondition": 0.0}, " without the spatial preconditioner"),
               (SHORT_RUN_OPTIMISER_ON_CPU, SHORT_RUN_OPTIMISER, ", Adam beta1 0.9 and EMA weight 0.02"),
               (LONG_RUN_ON_CPU, LONG_RUN, ", 4000 steps on 32-sample footprint targets instead of 1000 on 256"),
               (LONGER_RUN_ON_CPU, LONGER_RUN, ", 8000 steps on 32-sample footprint targets instead of 1000 on 256 "
                                               "(twice the gated model's: NeuMIP learns a flat metal's lobe slowly)"),
               (SMALL_INIT_ON_CPU, SMALL_INIT, ", latents initialised at standard deviation 0.1 instead of 1"),
               (HALVED_RATE_ON_CPU, HALVED_RATE, ", the learning rate halved at 50 % and 75 % of the steps"))


#: the models whose output a fit bounds by its largest target (`multiscale.Config.output_bound`, not in the paper):
#: their "paper" and "cpu" presets leave it unbounded, as the paper's model is
BOUNDED_OUTPUT = ("multiscale", "tripleplane")
PAPER_UNBOUNDED = {
    "paper": Preset("the paper's model and recipe, sized for a GPU (its output unbounded)", recipe="paper",
                    overrides={"model.output_bound": False}),
    "cpu": Preset("the paper's model along the fastest CPU path we measured (its output unbounded)", recipe="cpu",
                  overrides={"model.output_bound": False}),
}


def recommended(model: str) -> Preset:
    """The "recommended" preset of `model`: the paper's model sized to the device, trained with
    `relative_l2_robust` (Eq. 10 up to relative residual 10, a log tail beyond) instead of Eq. 10 and the gradient's
    global norm clipped at 1 (the typical norm is 0.5-3; one step's norm of ~900 stalled Adam); on the CPU recipe
    (1000 steps, 0.2 % of the paper's) at learning rate 1e-2 instead of the paper's 3e-3, which every model fits
    better in so few steps, without the spatial preconditioner where that was measured better
    (UNPRECONDITIONED_ON_CPU), with the short-run optimiser (SHORT_RUN_OPTIMISER_ON_CPU), the long run
    (LONG_RUN_ON_CPU, LONGER_RUN_ON_CPU), small initial latents (SMALL_INIT_ON_CPU) and the halved late rate
    (HALVED_RATE_ON_CPU); the output bounded by the fit's largest target (BOUNDED_OUTPUT, a model default); "paper"
    and "cpu" keep Eq. 10 (`relative_l2_mix`) unclipped at 3e-3 with the paper's Adam and EMA, unbounded.
    Evidence: benchmarks/studies/multiscale/results/polished_metal_stability.md (last section), selection_free.md
    and NOTES.md's decision table."""
    cpu, said = {"recipe.lr": 1e-2}, ""
    for models, overrides, description in CPU_CHANGES:
        if model in models:
            cpu.update(overrides)
            said += description
    return Preset(
        "the paper's model, sized to the device, with the robust loss (Eq. 10 up to relative residual 10, a log "
        "tail beyond) and gradients clipped at norm 1 (no blow-up on polished metal or stall after a loss spike)"
        + ("; its output bounded by the largest training target (no fireflies at grazing angles)"
           if model in BOUNDED_OUTPUT else "") + "; "
        "on a CPU at learning rate 1e-2" + said
        + " (a lower mean FLIP on every crop measured than with the paper's settings at the CPU recipe)",
        overrides={"recipe.loss": "relative_l2_robust", "recipe.grad_clip": 1.0}, by_recipe={"cpu": cpu})


#: when to choose each model, from issue 55's selection-free protocol (random 64^2 crops, the default recipe) and
#: larger sources (benchmarks/studies/multiscale/results/selection_free.md), as `neumat list` shows it
MEASURED = {
    "multiscale": "the default for texture sets of at most 2 x 256^2 texels with normal detail, metals and "
                  "near-mirrors (on a CPU; `neumat.methods.latent_mlp.regime`): at the CPU default (latents "
                  "initialised at std 0.1), over "
                  "all 29 random 64^2 crops x 2 seeds (session 64), mean FLIP over 9 scales below tripleplane's on "
                  "44 of 58 (76 %), every Metal027 and Leather05 pair among them (0.93-1.00x); on larger sources "
                  "0.72x (a 256^2 leather crop) and 0.96x (the whole 1K plaster set), 1.05-1.09x on the whole 1K "
                  "fabric set (session 63); on the six whole 1K sets at both seeds (the multiscale suite, session "
                  "75) the last of the neural models on average, 1.14-2.33x the best one's FLIP; against NeuMIP "
                  "0.99x its FLIP on average on four procedural 256^2 sets, 1.13x at 512^2 (session 76)",
    "tripleplane": "the default on a CPU for flat, rough dielectric texture sets (mean normal tilt < 3 degrees, "
                   "roughness >= 0.2, metalness < 0.5): at the CPU default (std 0.1), over the 29 random crops x 2 "
                   "seeds (session 64), ahead of the gated model on every Wood092 pair (1.01-1.16x) and six "
                   "near-ties (at most 1.06x), behind it on the flat metal (Metal027 0.95-0.98x) and where normals "
                   "vary; on the whole 1K fabric set 0.92-0.95x the gated model's (session 63); on the whole 1K "
                   "Wood092 set the best of the five models at both seeds (the multiscale suite, session 75)",
    "neumip": "the default on a CPU for texture sets of more than 2 x 256^2 texels with normal detail, metals and "
              "near-mirrors (a 512^2 or a whole 1K set): ahead of the gated model on 3 of 4 procedural 512^2 sets "
              "and tied on the fourth, and on 512^2 crops of Metal027 and Plaster001 at two seeds (session 76); on "
              "the six whole 1K sets at both seeds (the multiscale suite, session 75) the best model on 9 of the 10 "
              "such pairs (mean FLIP over 9 scales 0.0367 against the gated model's 0.0504, means over the six), "
              "and on the 4 held-out procedural 1K sets; on 64^2 crops a baseline: over the 29 random crops x 2 "
              "seeds at 4000 steps (sessions 65-66), mean FLIP 1.07x "
              "tripleplane's (median; 0.87-1.06x on sets with normal detail, 1.1-1.56x on flat ones: Leather05, "
              "Metal027, Wood092, a brushed metal), still learning on the flat metals; at its CPU default, 8000 "
              "steps (sessions 67, 69), 0.77-1.35x tripleplane's default fit on all 58 (crop, seed) pairs of the "
              "protocol",
    "neumip-frame": "a baseline: over the 29 random crops x 2 seeds at 4000 steps (sessions 65-66), mean FLIP "
                    "1.07x tripleplane's (median; 0.84-1.08x on sets with normal detail, 1.1-1.65x on flat ones); "
                    "at its CPU default, 8000 steps with the rate halved at 50 % and 75 % (session 69), 0.59-1.28x "
                    "tripleplane's default fit on all 58 (crop, seed) pairs measured (flat sets, the polished "
                    "plate and the held-out sets with normal detail)",
    "neumip-offset": "a baseline: over the 29 random crops x 2 seeds at 4000 steps (sessions 65-66), mean FLIP "
                     "1.07x tripleplane's (median; 0.84-1.06x on sets with normal detail, 1.1-1.55x on flat ones); "
                     "at its CPU default, 8000 steps (sessions 67, 69), 0.78-1.34x tripleplane's default fit on "
                     "all 58 (crop, seed) pairs of the protocol",
    "nbrdf-uv": "a baseline: over the 29 random crops x 2 seeds at the CPU default (sessions 65-66), mean FLIP "
                "1.04x tripleplane's (median; 0.74-1.21x, up to 1.34x on Wood092)",
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
                           drjit=DRJIT.get(name),
                           presets={"recommended": recommended(name), **(PAPER_UNBOUNDED if name in BOUNDED_OUTPUT
                                                                        else {})},
                           measured=MEASURED.get(name, "")))
