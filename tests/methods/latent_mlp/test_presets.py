"""The latent-texture models' recommended preset: on a CPU the measured CPU settings (lr 1e-2, no spatial
preconditioner, the short-run optimiser and small initial latents where those were measured better), on a GPU the
paper's rate, preconditioner and initial scale; paper and cpu keep the paper's. The CPU budget: 4000 steps for the
gated model, tripleplane and nbrdf-uv, 8000 for the NeuMIP variants, the paper's 1000 for ggx-mipmap; neumip-frame's
rate halved at 50 % and 75 % of them, the others' constant."""
import neumat.methods  # noqa: F401  (registers the models)
from neumat.fit.preset import resolve_preset
from neumat.methods.latent_mlp import (HALVED_RATE_ON_CPU, LONG_RUN_ON_CPU, LONGER_RUN_ON_CPU,
                                      SHORT_RUN_OPTIMISER_ON_CPU, SMALL_INIT_ON_CPU, UNPRECONDITIONED_ON_CPU)

MODELS = ("multiscale", "tripleplane", "neumip", "neumip-frame", "neumip-offset", "nbrdf-uv", "ggx-mipmap")


def test_recommended_on_a_cpu_and_elsewhere():
    for name in MODELS:
        cpu = resolve_preset(name, "recommended", device="cpu")
        gpu = resolve_preset(name, "recommended", device="cuda")
        paper = resolve_preset(name, "paper")
        assert cpu.recipe_name == "cpu" and cpu.recipe.lr == 1e-2, name
        assert gpu.recipe_name == "paper" and gpu.recipe.lr == paper.recipe.lr == 3e-3, name
        assert cpu.recipe.loss == gpu.recipe.loss == "relative_l2_robust" and cpu.recipe.grad_clip == 1.0, name
        assert resolve_preset(name, "cpu").recipe.lr == 3e-3, name
        expected = 0.0 if name in UNPRECONDITIONED_ON_CPU else 10.0
        assert cpu.config.spatial_precondition == expected, name
        assert gpu.config.spatial_precondition == paper.config.spatial_precondition == 10.0, name
        short = name in SHORT_RUN_OPTIMISER_ON_CPU
        assert (tuple(cpu.recipe.betas), cpu.recipe.ema) == (((0.9, 0.999), 0.02) if short else ((0.99, 0.999), 0.005))
        assert (tuple(gpu.recipe.betas), gpu.recipe.ema) == (tuple(paper.recipe.betas), paper.recipe.ema) \
            == ((0.99, 0.999), 0.005), name
        if name in SMALL_INIT_ON_CPU:
            assert cpu.config.init_std == 0.1, name
            assert gpu.config.init_std == paper.config.init_std == 1.0, name
        steps = 8000 if name in LONGER_RUN_ON_CPU else 4000 if name in LONG_RUN_ON_CPU else 1000
        assert cpu.recipe.steps == steps, name
        assert gpu.recipe.steps == paper.recipe.steps == 500_000, name
        assert cpu.recipe.schedule == ("halves" if name in HALVED_RATE_ON_CPU else "step"), name
        assert gpu.recipe.schedule == paper.recipe.schedule == "step", name
        # a user's --set wins over the preset's
        assert resolve_preset(name, "recommended", device="cpu", overrides={"recipe.steps": 50}).recipe.steps == 50
        assert resolve_preset(name, "recommended", device="cpu",
                              overrides={"recipe.schedule": "step"}).recipe.schedule == "step"
        assert resolve_preset(name, "recommended", device="cpu",
                              overrides={"model.spatial_precondition": 3.0}).config.spatial_precondition == 3.0
