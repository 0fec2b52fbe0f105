"""Half-aware training (`neumat.models.half_precision`): the straight-through forward is `half_rounded`'s model and
its gradient is the gradient at the rounded parameters; snapping makes a model its own fp16 export; a
neural-appearance fit with half_finish ends on a model that `half_rounded` leaves unchanged, one without does not."""
from __future__ import annotations

import copy
from dataclasses import replace

import pytest
import torch

from neumat.core.errors import InputError
from neumat.core.query import Query
from neumat.fit.method import recipe_for
from neumat.methods.neural_appearance.train import config_for_source
from neumat.fit.trainer import fit
from neumat.models.half_precision import half_rounded, is_half_exact, snap_to_half_, with_half_parameters
from neumat.nn import cpu_kernels
from neumat.methods.latent_mlp.neumip import NeuMIP
from neumat.methods.neural_appearance.model import NeuralAppearance
from neumat.reflectance.procedural_texture import procedural_texture_set
from neumat.reflectance.svbrdf import SVBRDF
from neumat.warp.hemisphere import sample_cosine_hemisphere


def _model() -> NeuralAppearance:
    torch.manual_seed(3)
    model = NeuralAppearance(spatial_size=8, surface_features=7)
    with torch.no_grad():  # move every parameter off the fp16 grid, the frame weights well away from zero
        for p in model.parameters():
            p.add_(torch.randn_like(p) * 0.3)
    return model


def _queries(n: int = 256, seed: int = 1) -> Query:
    g = torch.Generator().manual_seed(seed)
    return Query(wi=sample_cosine_hemisphere(torch.rand(n, 2, generator=g)),
                 wo=sample_cosine_hemisphere(torch.rand(n, 2, generator=g)), uv=torch.rand(n, 2, generator=g),
                 lod=torch.rand(n, generator=g) * 2)


def _relative(got: torch.Tensor, ref: torch.Tensor) -> float:
    return float(((got - ref).abs() / ref.abs().clamp(min=1e-6)).max().detach())


def test_straight_through_forward_is_half_rounded_and_its_gradient_is_taken_there():
    model, q = _model(), _queries()
    assert model.frame is not None and model.frame.weight_scale != 1.0  # the scaled-weight case is exercised
    half = half_rounded(model)
    out = with_half_parameters(model, lambda: model.eval(q))
    with torch.no_grad(), cpu_kernels.switched_off():  # the operations `out` ran (a fused kernel rounds otherwise)
        ref, fp32 = half.eval(q), model.eval(q)
    assert _relative(out, ref) < 1e-5
    assert _relative(fp32, ref) > 1e-4  # the rounding is visible: the test could fail if nothing were rounded
    # gradient: d sum(log f) / d p at the rounded parameters, on a copy holding them (frame weights unfolded)
    out.log().sum().backward()
    at_rounded = copy.deepcopy(model)
    snap_to_half_(at_rounded)
    at_rounded.zero_grad()
    at_rounded.eval(q).log().sum().backward()
    grads = dict(at_rounded.named_parameters())
    checked = 0
    for name, p in model.named_parameters():
        if p.grad is None:
            assert grads[name].grad is None, name
            continue
        torch.testing.assert_close(p.grad, grads[name].grad, rtol=1e-4, atol=1e-6, msg=name)
        checked += 1
    assert checked >= 6
    # the model itself is left as it was
    with torch.no_grad(), cpu_kernels.switched_off():
        assert torch.equal(model.eval(q), fp32)


def test_snap_makes_the_model_its_own_fp16_export():
    model, q = _model(), _queries()
    assert not is_half_exact(model)
    snap_to_half_(model)
    assert is_half_exact(model)
    half = half_rounded(model)
    with torch.no_grad():
        assert _relative(model.eval(q), half.eval(q)) < 1e-6
        assert _relative(model.pdf(q), half.pdf(q)) < 1e-6
    for name, p in half.named_parameters():  # the folded frame weights are fp16 values too
        assert torch.equal(p, p.half().float()), name


def test_preconditioned_textures_are_refused():
    model = NeuMIP(spatial_size=8)
    assert model.spatial.precondition is not None
    with pytest.raises(InputError, match="preconditioned or vector-quantised"):
        snap_to_half_(model)


def _fit(half_finish: float) -> NeuralAppearance:
    source = SVBRDF(procedural_texture_set("bumps", 8, seed=0), samples=2)
    torch.manual_seed(0)
    model = NeuralAppearance(**config_for_source(source))
    recipe = recipe_for("neural-appearance")
    recipe = replace(recipe, steps=24, batch_size=64, options={**recipe.options, "half_finish": half_finish})
    fit(model, source, recipe, progress=False)
    return model


def test_a_half_aware_fit_ends_on_its_own_fp16_export_and_a_plain_one_does_not():
    q = _queries(512, seed=2)
    plain, finished = _fit(0.0), _fit(0.25)
    assert is_half_exact(finished) and not is_half_exact(plain)
    with torch.no_grad():
        assert _relative(half_rounded(finished).eval(q), finished.eval(q)) < 1e-5
        assert _relative(half_rounded(finished).pdf(q), finished.pdf(q)) < 1e-5
        assert _relative(half_rounded(plain).eval(q), plain.eval(q)) > 1e-4


@pytest.mark.parametrize("bad", [-0.1, 1.5, True, "x"])
def test_half_finish_is_checked(bad):
    source = SVBRDF(procedural_texture_set("bumps", 8, seed=0), samples=2)
    model = NeuralAppearance(**config_for_source(source))
    recipe = recipe_for("neural-appearance")
    with pytest.raises(InputError, match=r"^neural-appearance recipe options: option.half_finish: expected "):
        fit(model, source, replace(recipe, steps=2, batch_size=8, options={**recipe.options, "half_finish": bad}),
            progress=False)
