"""Russian-roulette mip-level selection of the latent-pyramid models (Zeltner et al. 2024 Sec. 4.1):
one level per query in training, its expectation in eval, against the trilinear blend; the GLSL and Slang
exports compute the same expectation."""
import pytest
import torch

from neumat import InputError, Query
from neumat.export.glsl import export_glsl
from neumat.export.slang import export_slang
from neumat.methods.neural_appearance.model import NeuralAppearance
from neumat.nn.latent_texture import LatentPyramid, footprint_lod, trilinear
from neumat.testing.parity import glsl_eval, opengl_available
from neumat.testing.slang_parity import SlangKernel, slang_available, slang_eval


def _pyramid():
    torch.manual_seed(0)
    return LatentPyramid(4, 16, init_std=1.0)


def test_roulette_reads_one_level_and_averages_to_the_trilinear_blend():
    p = _pyramid()
    g = torch.Generator().manual_seed(1)
    uv = torch.rand(64, 2, generator=g)
    lod = torch.rand(64, generator=g) * 3.5
    with torch.no_grad():
        fine = trilinear(list(p.raw), uv, lod.floor())
        coarse = trilinear(list(p.raw), uv, (lod.floor() + 1).clamp(max=4))
        blend = p(uv, lod=lod)
        t = p.level_fraction(None, lod, 64)
        torch.testing.assert_close(t, lod - lod.floor())
        torch.testing.assert_close(p(uv, lod=lod, level_u=torch.ones(64)), fine)
        torch.testing.assert_close(p(uv, lod=lod, level_u=torch.zeros(64)), torch.where(t[:, None] > 0, coarse, fine))
        torch.testing.assert_close((1 - t)[:, None] * fine + t[:, None] * coarse, blend, atol=1e-5, rtol=1e-5)
        # a uniform level_u picks the coarser level with probability t
        u = torch.rand(64, 4000, generator=g)
        picked = (u < t[:, None]).float().mean(1)
        assert float((picked - t).abs().max()) < 0.04


def test_footprint_roulette_uses_the_probe_level():
    p = _pyramid()
    g = torch.Generator().manual_seed(2)
    uv = torch.rand(32, 2, generator=g)
    a = torch.randn(32, 2, 2, generator=g) * 0.05
    cov = a @ a.transpose(1, 2) + 1e-6 * torch.eye(2)
    lod = footprint_lod(cov, 16, 16).clamp(0, 4)
    t = p.level_fraction(cov, None, 32)
    torch.testing.assert_close(t, lod - lod.floor())
    with torch.no_grad():
        mixed = (1 - t)[:, None] * p(uv, cov, level_u=torch.ones(32)) + t[:, None] * p(uv, cov, level_u=torch.zeros(32))
        torch.testing.assert_close(mixed, p(uv, cov), atol=1e-5, rtol=1e-5)   # probes are linear in the levels


def test_roulette_model_trains_on_one_level_and_evaluates_the_expectation():
    torch.manual_seed(3)
    model = NeuralAppearance(spatial_size=16, level_selection="roulette", albedo=True)
    g = torch.Generator().manual_seed(4)
    wi = torch.nn.functional.normalize(torch.rand(128, 3, generator=g) + torch.tensor([0, 0, 0.5]), dim=-1)
    wo = torch.nn.functional.normalize(torch.rand(128, 3, generator=g) + torch.tensor([0, 0, 0.5]), dim=-1)
    q = Query(wi, wo, uv=torch.rand(128, 2, generator=g), lod=torch.rand(128, generator=g) * 3)
    model.eval()
    with torch.no_grad():
        fine = model.decode_outputs(model.spatial_latent(q, torch.ones(128)), q)
        coarse = model.decode_outputs(model.spatial_latent(q, torch.zeros(128)), q)
        t = (q.lod - q.lod.floor()).unsqueeze(-1)
        torch.testing.assert_close(model.eval(q), ((1 - t) * fine + t * coarse)[:, :3])
        torch.testing.assert_close(model.albedo(q), ((1 - t) * fine + t * coarse)[:, 3:])
        assert not torch.allclose(model.eval(q), model.decode(model.spatial_latent(q), q))   # not the trilinear z
        s = model.sample(q, torch.rand(128, 2, generator=g))
        ok = s.pdf > 0
        torch.testing.assert_close(s.weight[ok], (model.eval(q.with_wo(s.wo)) * (s.wo[:, 2] / s.pdf)[:, None])[ok])
    model.train()
    with torch.no_grad():
        torch.manual_seed(5)
        z = model.spatial_latent(q)
        picked_fine = (z - model.spatial_latent(q, torch.ones(128))).abs().amax(-1) < 1e-6
        picked_coarse = (z - model.spatial_latent(q, torch.zeros(128))).abs().amax(-1) < 1e-6
    assert bool((picked_fine | picked_coarse).all()) and picked_fine.any() and picked_coarse.any()


def test_roulette_config_is_checked():
    with pytest.raises(InputError, match="level_selection"):
        NeuralAppearance(spatial_size=16, level_selection="random")


def _exported_model():
    torch.manual_seed(6)
    model = NeuralAppearance(spatial_size=16, level_selection="roulette", albedo=True).train(False)
    with torch.no_grad():
        for p in model.parameters():
            p.add_(0.1 * torch.randn_like(p))
    g = torch.Generator().manual_seed(7)
    wi = torch.nn.functional.normalize(torch.rand(512, 3, generator=g) + torch.tensor([0, 0, 0.3]), dim=-1)
    wo = torch.nn.functional.normalize(torch.rand(512, 3, generator=g) + torch.tensor([0, 0, 0.3]), dim=-1)
    a = torch.randn(512, 2, 2, generator=g) * torch.exp2(torch.rand(512, 1, 1, generator=g) * -7)
    uv = torch.rand(512, 2, generator=g) * 3 - 1
    return (model, Query(wi, wo, uv=uv, footprint=a @ a.transpose(1, 2) + 1e-8 * torch.eye(2)),
            Query(wi, wo, uv=uv, lod=torch.rand(512, generator=g) * 5 - 1))


def _relative(got, ref):
    """Largest relative difference. The exports measure 1.2-1.4e-6 against eval; the trilinear decode differs from
    eval by 1.8e-4 on these queries, so the 1e-5 bound tells the two apart."""
    return float(((got - ref).abs() / ref.abs().clamp(min=1e-6)).max())


@pytest.mark.skipif(not opengl_available(), reason="no moderngl or no headless OpenGL 3.3 context (EGL)")
def test_glsl_export_computes_the_two_level_expectation():
    model, footprint, lod = _exported_model()
    export = export_glsl(model, "fp32")
    with torch.no_grad():
        assert _relative(glsl_eval(export, footprint), model.eval(footprint)) < 1e-5
        assert _relative(glsl_eval(export, lod), model.eval(lod)) < 1e-5


@pytest.mark.skipif(not slang_available(), reason="slangpy is not installed or its CPU device cannot be created")
def test_slang_export_computes_the_two_level_expectation():
    model, footprint, lod = _exported_model()
    kernel = SlangKernel(export_slang(model, "fp32"))
    with torch.no_grad():
        assert _relative(slang_eval(kernel, footprint), model.eval(footprint)) < 1e-5
        assert _relative(slang_eval(kernel, lod), model.eval(lod)) < 1e-5
        assert _relative(slang_eval(kernel, footprint, "albedo"), model.albedo(footprint)) < 1e-5
