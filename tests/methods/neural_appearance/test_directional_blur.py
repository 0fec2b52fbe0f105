"""Directionally blurred targets (Zeltner et al. Sec. 5) and the training options of the neural-appearance
recipe (half/difference directions, blurring, a separate sampler batch)."""
import math
from dataclasses import replace

import pytest
import torch

from neumat.core.errors import InputError
from neumat.core.query import Query
from neumat.methods.neural_appearance.directional_blur import blur_angle, blurred_eval, sample_cone
from neumat.fit.method import recipe_for
from neumat.fit.trainer import fit
from neumat.methods.neural_appearance.model import NeuralAppearance
from neumat.reflectance.analytic import GGX, Lambert
from neumat.reflectance.procedural_texture import procedural_texture_set
from neumat.reflectance.svbrdf import SVBRDF


def _fit(model, source, options=(), **changes):
    """The trainer with neural-appearance's recipe, `changes` to its fields and `options` to its options."""
    recipe = recipe_for("neural-appearance")
    return fit(model, source, replace(recipe, options={**recipe.options, **dict(options)}, **changes), progress=False)


def test_cone_directions_are_uniform_on_the_cap():
    g = torch.Generator().manual_seed(0)
    axis = torch.nn.functional.normalize(torch.randn(64, 3, generator=g, dtype=torch.float64), dim=-1)
    alpha = math.radians(20)
    w = sample_cone(axis, alpha, torch.rand(64, 4096, 2, generator=g, dtype=torch.float64))
    cos = (w * axis[:, None, :]).sum(-1)
    torch.testing.assert_close(w.norm(dim=-1), torch.ones(64, 4096, dtype=torch.float64))
    assert float(cos.min()) >= math.cos(alpha) - 1e-12
    # uniform on the cap: cos(theta) is uniform on [cos(alpha), 1], mean (1 + cos alpha) / 2, var (1 - cos a)^2 / 12
    n = cos.numel()
    mean, sd = (1 + math.cos(alpha)) / 2, (1 - math.cos(alpha)) / math.sqrt(12)
    assert abs(float(cos.mean()) - mean) < 4 * sd / math.sqrt(n)
    # and the azimuth around the axis is uniform: the mean direction is the axis itself
    resultant = torch.nn.functional.normalize(w.mean(1), dim=-1)
    assert float((resultant * axis).sum(-1).min()) > 1 - 1e-4


def test_blur_schedule_and_plain_targets():
    assert blur_angle(0, 100, 10.0, 0.5) == pytest.approx(math.radians(10))
    assert blur_angle(25, 100, 10.0, 0.5) == pytest.approx(math.radians(5))
    assert blur_angle(50, 100, 10.0, 0.5) == 0.0 and blur_angle(99, 100, 10.0, 0.5) == 0.0
    assert blur_angle(0, 100, 0.0, 0.5) == 0.0
    wi = torch.tensor([[0.0, 0.6, 0.8]]).repeat(16, 1)
    q = Query(wi, torch.tensor([[0.3, 0.0, 0.9539392]]).repeat(16, 1))
    g = torch.Generator().manual_seed(1)
    ggx = GGX(roughness=0.1, fresnel="none")
    torch.testing.assert_close(blurred_eval(ggx, q, 0.0, 4, g), ggx.eval(q))
    # a constant BRDF is unchanged by a cone that stays above the horizon
    torch.testing.assert_close(blurred_eval(Lambert(0.7), q, math.radians(10), 8, g), Lambert(0.7).eval(q))


def test_blur_spreads_a_narrow_peak():
    """At the mirror direction of a sharp GGX lobe the blurred value is lower, away from it higher; the blurred
    value equals the lobe's mean over the cap (brute force with many cone samples, float64)."""
    ggx = GGX(roughness=0.05, fresnel="none")
    wi = torch.tensor([[0.0, 0.5, math.sqrt(0.75)]], dtype=torch.float64)
    mirror = torch.tensor([[0.0, -0.5, math.sqrt(0.75)]], dtype=torch.float64)
    off = torch.nn.functional.normalize(mirror + torch.tensor([[0.15, 0.0, 0.0]], dtype=torch.float64), dim=-1)
    g = torch.Generator().manual_seed(2)
    alpha = math.radians(8)
    peak = blurred_eval(ggx, Query(wi, mirror), alpha, 20000, g)
    side = blurred_eval(ggx, Query(wi, off), alpha, 20000, g)
    assert float(peak[0, 0]) < 0.5 * float(ggx.eval(Query(wi, mirror))[0, 0])
    assert float(side[0, 0]) > 1.5 * float(ggx.eval(Query(wi, off))[0, 0])     # measured 1.97x
    w = sample_cone(mirror, alpha, torch.rand(1, 200000, 2, generator=g, dtype=torch.float64))[0]
    brute = ggx.eval(Query(wi.expand(len(w), 3), w)).mean(0)
    assert abs(float(peak[0, 0]) - float(brute[0])) < 0.03 * float(brute[0])


def test_training_options_run_and_bad_values_raise():
    source = SVBRDF(procedural_texture_set("bumps", 8, seed=0), samples=2)
    torch.manual_seed(0)
    model = NeuralAppearance(spatial_size=8)
    fit = _fit(model, source, dict(blur_degrees=5.0, blur_samples=2, sampler_batch="separate"),
               queries="rusinkiewicz", steps=12, batch_size=64, log_every=3)
    assert [h["phase"] for h in fit.history][-1] == "latents" and all(math.isfinite(h["brdf loss"])
                                                                      for h in fit.history)
    with pytest.raises(InputError, match="queries"):
        _fit(model, source, queries="uniform", steps=2, batch_size=8)
    for bad, why in ((dict(blur_degrees=-1.0), r"option.blur_degrees: expected a value in \[0, 90\], got -1.0"),
                     (dict(blur_until=0.0), r"option.blur_until: expected a value in \(0, 1\], got 0.0"),
                     (dict(blur_samples=0), r"option.blur_samples: expected a value >= 1, got 0"),
                     (dict(sampler_batch="twice"), r"option.sampler_batch: expected one of 'shared', 'separate', "
                                                   r"got 'twice'"),
                     (dict(blur_degree=1.0), r"unknown key\(s\) blur_degree \(known: blur_degrees, ")):
        with pytest.raises(InputError, match="^neural-appearance recipe options: " + why):
            _fit(model, source, bad, steps=2, batch_size=8)


def test_a_separate_sampler_batch_still_trains_the_sampler():
    """sampler_batch="separate" (the paper's second batch): the sampler's KL, measured on batches the BRDF never
    saw, falls during training."""
    source = SVBRDF(procedural_texture_set("bumps", 8, seed=0), samples=2)
    torch.manual_seed(0)
    model = NeuralAppearance(spatial_size=8)
    fit = _fit(model, source, dict(sampler_batch="separate"), steps=200, batch_size=256, log_every=50)
    kl = [h["sampler loss"] for h in fit.history]
    assert kl[-1] < 0.97 * kl[0], kl                   # measured 1.727 -> 1.606 (shared batch: 1.779 -> 1.598)
