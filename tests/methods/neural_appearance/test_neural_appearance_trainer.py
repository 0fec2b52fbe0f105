"""Neural-appearance and the proxy sampler through the one trainer: a fit interrupted in the encoder phase or in
the half-aware part of the latents phase resumes from its checkpoint bit for bit (fresh source and model, as in a
new process), the device follows the argument, the source-derived config."""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest
import torch

from neumat.methods.neural_appearance.proxy_train import fit_sampler
from neumat.fit.method import recipe_for
from neumat.methods.neural_appearance.train import config_for_source
from neumat.fit.trainer import fit
from neumat.methods.neural_appearance.model import NeuralAppearance
from neumat.methods.neural_appearance.proxy_sampler import ProxySampler, SampledMaterial
from neumat.reflectance.analytic import GGX
from neumat.reflectance.procedural_texture import procedural_texture_set
from neumat.reflectance.svbrdf import SVBRDF

SIZE = 8
STEPS = 20             # 10 encoder steps, bake, 10 latent steps (the last 5 half-aware)


class Interrupt(Exception):
    pass


def _source() -> SVBRDF:
    return SVBRDF(procedural_texture_set("bumps", SIZE, seed=0), samples=2)


def _na_fit(checkpoint=None, resume=False, stop_at=None, device=None):
    """A tiny fit with every random draw in play (blur over both phases, albedo estimates), a fresh source and
    model each time; `stop_at`: raise Interrupt at that step's record."""
    source = _source()
    torch.manual_seed(0)
    model = NeuralAppearance(**config_for_source(source), albedo=True)
    recipe = recipe_for("neural-appearance")
    recipe = replace(recipe, steps=STEPS, batch_size=32, log_every=1, checkpoint_every=3,
                     options={**recipe.options, "blur_degrees": 10.0, "blur_samples": 2, "blur_until": 1.0,
                              "half_finish": 0.5})

    def callback(record):
        if record["step"] == stop_at:
            raise Interrupt

    result = fit(model, source, recipe, device=device, progress=False, checkpoint=checkpoint, resume=resume,
                 callback=callback if stop_at else None)
    return model, result


def _strip(history):
    return [{k: v for k, v in r.items() if k != "seconds"} for r in history]


@pytest.fixture(scope="module")
def uninterrupted():
    return _na_fit()


@pytest.mark.parametrize("stop_at, saved, phase", [(7, 6, "encoder"), (16, 15, "latents")])
def test_neural_appearance_resumes_bit_for_bit(uninterrupted, tmp_path, stop_at, saved, phase):
    ref_model, ref = uninterrupted
    assert [r["phase"] for r in ref.history].count("encoder") == STEPS // 2
    ckpt = tmp_path / "na.ckpt"
    with pytest.raises(Interrupt):
        _na_fit(checkpoint=ckpt, stop_at=stop_at)
    assert torch.load(ckpt, weights_only=True)["step"] == saved
    assert ref.history[saved - 1]["phase"] == phase
    model, res = _na_fit(checkpoint=ckpt, resume=True)
    ref_state, state = ref_model.state_dict(), model.state_dict()
    assert ref_state.keys() == state.keys()
    for k in ref_state:
        assert torch.equal(ref_state[k], state[k]), k
    assert _strip(res.history) == _strip(ref.history) and len(res.history) == STEPS


def test_device_follows_the_argument(uninterrupted):
    model, res = _na_fit(device=torch.device("cpu"))
    assert all(p.device.type == "cpu" for p in model.parameters())
    assert _strip(res.history) == _strip(uninterrupted[1].history)
    root = Path(__file__).resolve().parents[3] / "src" / "neumat" / "methods" / "neural_appearance"
    for path in (root / "train.py", root / "proxy_train.py", root / "proxy_recipe.py"):
        assert '"cpu"' not in path.read_text(), path             # no tensor on a hard-coded device


def test_config_for_source():
    assert config_for_source(_source()) == {"spatial_size": SIZE, "surface_features": 8}
    assert config_for_source(SVBRDF(procedural_texture_set("bumps", 12, seed=0))) == {"spatial_size": 8,
                                                                                       "surface_features": 8}
    assert config_for_source(GGX(0.3)) == {}


def test_proxy_sampler_fit_resumes_bit_for_bit(tmp_path):
    """fit_sampler is the trainer on SampledMaterial(material, sampler); interrupted after its checkpoint at step
    8 of 12, it resumes to the same sampler."""
    recipe = replace(recipe_for("proxy-sampler"), steps=12, batch_size=64, log_every=4, checkpoint_every=4)

    def run(**kw):
        torch.manual_seed(0)
        ggx = GGX(0.2)
        sampler = ProxySampler()
        return sampler, fit(SampledMaterial(ggx, sampler), ggx, recipe, progress=False, **kw)

    ref_sampler, ref = run()
    torch.manual_seed(0)
    wrapped = fit_sampler(GGX(0.2), steps=12, batch=64, progress=False)
    for k, v in ref_sampler.state_dict().items():
        assert torch.equal(v, wrapped.sampler.state_dict()[k]), k

    def stop_at_8(record):
        if record["step"] == 8:
            raise Interrupt

    ckpt = tmp_path / "sampler.ckpt"
    with pytest.raises(Interrupt):
        run(checkpoint=ckpt, callback=stop_at_8)
    sampler, res = run(checkpoint=ckpt, resume=True)
    for k, v in ref_sampler.state_dict().items():
        assert torch.equal(v, sampler.state_dict()[k]), k
    assert _strip(res.history) == _strip(ref.history)


def test_encoder_lr_scale_sets_the_encoder_phase_rate_only():
    """Option encoder_lr_scale multiplies the rate of the encoder phase: at 1e-3 of it the encoder barely leaves its
    initial weights (Adam's step is proportional to the rate) while the latents phase still trains at the recipe's."""
    def run(scale):
        source = _source()
        torch.manual_seed(0)
        model = NeuralAppearance(**config_for_source(source))
        start = [p.detach().clone() for p in model.encoder.parameters()]
        recipe = recipe_for("neural-appearance")
        recipe = replace(recipe, steps=STEPS, batch_size=32, lr=1e-2, log_every=1,
                         options={**recipe.options, "half_finish": 0.0, "encoder_lr_scale": scale})
        baked = {}
        result = fit(model, source, recipe, progress=False,
                     callback=lambda r: baked.setdefault("latents", model.spatial.raw[0].detach().clone())
                     if r["phase"] == "latents" else None)
        moved = sum((p.detach() - s).abs().sum().item() for p, s in zip(model.encoder.parameters(), start))
        latents = (model.spatial.raw[0].detach() - baked["latents"]).abs().sum().item()
        return moved, latents, result

    full, full_latents, _ = run(1.0)
    slow, slow_latents, result = run(1e-3)
    assert 0 < slow < 0.01 * full
    assert slow_latents > 0.1 * full_latents > 0  # the latents phase moves its latents at the recipe's rate
    assert all(r["lr"] > 0 for r in result.history)


def test_recommended_preset_on_a_cpu_and_elsewhere():
    """On a CPU the recommended preset runs the latents phase at 1e-2 and the encoder phase at 3e-3 (0.3 of it); on a
    GPU and in paper / cpu the paper's 3e-3 for both; a user's --set wins."""
    import neumat.methods  # noqa: F401  (registers the models)
    from neumat.fit.preset import resolve_preset

    cpu = resolve_preset("neural-appearance", "recommended", device="cpu")
    assert (cpu.recipe.lr, cpu.recipe.options["encoder_lr_scale"]) == (1e-2, 0.3)
    assert cpu.recipe.lr * cpu.recipe.options["encoder_lr_scale"] == pytest.approx(3e-3)
    for resolved in (resolve_preset("neural-appearance", "recommended", device="cuda"),
                     resolve_preset("neural-appearance", "paper"), resolve_preset("neural-appearance", "cpu")):
        assert (resolved.recipe.lr, resolved.recipe.options["encoder_lr_scale"]) == (3e-3, 1.0)
    mine = resolve_preset("neural-appearance", "recommended", device="cpu", overrides={"recipe.lr": 5e-3})
    assert mine.recipe.lr == 5e-3 and mine.recipe.options["encoder_lr_scale"] == 0.3
