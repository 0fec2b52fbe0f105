"""The Mitsuba 3 BSDF plugin: argument order and cosines against the Material itself, Mitsuba's own chi-square
test of its sampler, and renders against Mitsuba's built-in BSDFs of the same functions."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from neumat.core.errors import InputError
from neumat.core.material import Material
from neumat.core.query import Query
from mitsuba_util import bsdf_chi2_test, mi_vector, sphere_scene, to_torch
from neumat.catalog.modelfile import save_model
from neumat.io.texture_set import TextureSet
from neumat.methods.neural_appearance.model import NeuralAppearance
from neumat.reflectance.analytic import GGX, Lambert
from neumat.reflectance.svbrdf import SVBRDF

pytestmark = pytest.mark.mitsuba


@pytest.fixture(scope="module")
def mi():
    from mitsuba_util import mitsuba_or_skip
    mitsuba_or_skip()
    from neumat.integrations import mitsuba as plugin
    return plugin.register()


def _plugin():
    from neumat.integrations import mitsuba as plugin
    return plugin


def _random_dirs(n: int, gen: torch.Generator, below: float = 0.1) -> torch.Tensor:
    """n unit directions, a fraction `below` of them under the horizon."""
    v = torch.randn(n, 3, generator=gen)
    v[:, 2] = v[:, 2].abs() * torch.where(torch.rand(n, generator=gen) < below, -1.0, 1.0)
    return v / v.norm(dim=-1, keepdim=True)


def _interaction(mi, wi: torch.Tensor, uv: torch.Tensor):
    import drjit as dr
    si = dr.zeros(mi.SurfaceInteraction3f, wi.shape[0])
    si.wi = mi.Vector3f(*(mi.Float(c.contiguous()) for c in wi.T))
    si.uv = mi.Point2f(*(mi.Float(c.contiguous()) for c in uv.T))
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    return si


def _texture_set(size: int = 8) -> TextureSet:
    gen = torch.Generator().manual_seed(3)
    n = torch.randn(size, size, 3, generator=gen) * 0.3
    n[..., 2] = 1.0
    return TextureSet(color=torch.rand(size, size, 3, generator=gen), normal=n / n.norm(dim=-1, keepdim=True),
                      roughness=0.2 + 0.6 * torch.rand(size, size, generator=gen),
                      metalness=(torch.rand(size, size, generator=gen) > 0.5).float(),
                      height=torch.zeros(size, size))


MATERIALS = {
    "anisotropic ggx": lambda: GGX(alpha_x=0.4, alpha_y=0.1, material="gold"),
    "svbrdf": lambda: SVBRDF(_texture_set()),
}


@pytest.mark.parametrize("name", MATERIALS)
def test_eval_and_pdf_are_the_materials_with_mitsubas_argument_order(mi, name):
    material = MATERIALS[name]()
    bsdf = _plugin().bsdf(material)
    gen = torch.Generator().manual_seed(0)
    n = 4000
    viewer, light = _random_dirs(n, gen), _random_dirs(n, gen)
    uv = torch.rand(n, 2, generator=gen) * 3 - 1  # tiles: the plugin wraps uv into [0, 1)
    si = _interaction(mi, viewer, uv)
    ctx = mi.BSDFContext()
    value, pdf = bsdf.eval_pdf(ctx, si, mi_vector(mi, light))
    up = (viewer[:, 2] > 0) & (light[:, 2] > 0)
    # the material's incident slot gets si.wi (the viewer), as Mitsuba's `measured` feeds its tables
    q = Query(viewer[up], light[up], uv=torch.remainder(uv[up], 1.0))
    expected = material.eval(q).double() * light[up, 2:3].double()
    got_value, got_pdf = to_torch(value), to_torch(pdf)
    assert torch.allclose(got_value[up], expected, rtol=1e-4, atol=1e-6)
    assert torch.allclose(got_pdf[up], material.pdf(q).double(), rtol=1e-4, atol=1e-6)
    assert bool((got_value[~up] == 0).all()) and bool((got_pdf[~up] == 0).all())
    assert torch.allclose(to_torch(bsdf.eval(ctx, si, mi_vector(mi, light))), got_value)
    assert torch.allclose(to_torch(bsdf.pdf(ctx, si, mi_vector(mi, light))), got_pdf)
    # importance transport: si.wi is the light, wo the viewer; the same function with the other cosine
    importance = mi.BSDFContext(mi.TransportMode.Importance)
    swapped = to_torch(bsdf.eval(importance, _interaction(mi, light, uv), mi_vector(mi, viewer)))
    assert torch.allclose(swapped[up], material.eval(q).double() * viewer[up, 2:3].double(), rtol=1e-4, atol=1e-6)


@pytest.mark.parametrize("name", MATERIALS)
def test_sample_returns_its_pdf_and_eval_over_pdf(mi, name):
    material = MATERIALS[name]()
    bsdf = _plugin().bsdf(material)
    gen = torch.Generator().manual_seed(1)
    n = 4000
    viewer = _random_dirs(n, gen)
    si = _interaction(mi, viewer, torch.rand(n, 2, generator=gen))
    u = torch.rand(n, 2, generator=gen)
    ctx = mi.BSDFContext()
    bs, weight = bsdf.sample(ctx, si, mi.Float(torch.rand(n, generator=gen)),
                             mi.Point2f(mi.Float(u[:, 0].contiguous()), mi.Float(u[:, 1].contiguous())))
    wo, pdf, weight = to_torch(bs.wo).float(), to_torch(bs.pdf), to_torch(weight)
    ok = pdf > 0
    assert int(ok.sum()) > 0.85 * int((viewer[:, 2] > 0).sum())
    assert bool((weight[viewer[:, 2] <= 0] == 0).all())
    value, pdf_again = bsdf.eval_pdf(ctx, si, mi_vector(mi, wo / wo.norm(dim=-1, keepdim=True)))
    assert torch.allclose(to_torch(pdf_again)[ok], pdf[ok], rtol=2e-3, atol=1e-5)
    assert torch.allclose(weight[ok], to_torch(value)[ok] / pdf[ok, None], rtol=2e-3, atol=1e-5)


class _NaNs(Material):
    name = "nans"

    def eval(self, q):
        return torch.full((len(q), 3), float("nan"))


class _NoSampler(Material):
    """GGX without its sampler: the plugin must fall back to cosine-weighted sampling."""

    name = "ggx-no-sampler"

    def __init__(self):
        self.inner = GGX(0.3, fresnel="none")

    def eval(self, q):
        return self.inner.eval(q)

    def describe(self):
        return self.name


@pytest.mark.parametrize("material", [lambda: GGX(alpha_x=0.35, alpha_y=0.15, material="copper"),
                                      lambda: SVBRDF(_texture_set()), _NoSampler],
                         ids=["anisotropic ggx", "svbrdf", "no sampler"])
@pytest.mark.parametrize("theta", [0.3, 1.2])
def test_mitsuba_chi2_accepts_the_plugin_sampler(mi, material, theta):
    plugin = _plugin()
    bsdf = plugin.bsdf(material())
    with plugin.evaluated_mode():
        test = bsdf_chi2_test(mi, bsdf, theta, uv=(0.37, 0.61), sample_count=400_000, res=48)
        assert test.run(), test.messages


def _scene(mi, bsdf, spp: int, envmap: str, size: int = 48):
    """`sphere_scene` under the environment map `envmap`, depth 3."""
    return sphere_scene(mi, bsdf, spp, size, depth=3, lights={"env": {"type": "envmap", "filename": envmap}})


def _blocks(img: torch.Tensor, k: int = 4) -> torch.Tensor:
    h, w, c = img.shape
    return img.reshape(h // k, k, w // k, k, c).mean((1, 3))


def test_lambert_renders_like_mitsubas_diffuse(mi, shared_data):
    plugin = _plugin()
    env = str(shared_data / "envmap" / "studio_small_03_1k.hdr")
    ours = plugin.render(_scene(mi, plugin.bsdf(Lambert(albedo=(0.7, 0.5, 0.2))), 16, env))
    theirs = plugin.render(_scene(mi, {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.7, 0.5, 0.2]}},
                                  16, env))
    # the same warp (concentric cosine sampling) on the same random numbers: the same image up to float error
    assert torch.allclose(ours, theirs, rtol=1e-3, atol=1e-4)


def test_anisotropic_ggx_renders_like_mitsubas_roughconductor(mi, shared_data):
    """Frames, cosines and both sampling strategies: the difference to Mitsuba's own anisotropic GGX must be
    no larger than the noise between two seeds of Mitsuba's render (4 x 4-pixel blocks, 128 spp)."""
    plugin = _plugin()
    env = str(shared_data / "envmap" / "studio_small_03_1k.hdr")
    ours = _blocks(plugin.render(_scene(mi, {"type": "neumat", "material":
                                             "ggx:alpha_x=0.35,alpha_y=0.08,fresnel=none"}, 128, env)))
    theirs_bsdf = {"type": "roughconductor", "material": "none", "distribution": "ggx",
                   "alpha_u": 0.35, "alpha_v": 0.08}
    theirs = [_blocks(plugin.render(_scene(mi, theirs_bsdf, 128, env), seed=s)) for s in (1, 2)]
    noise = (theirs[0] - theirs[1]).pow(2).mean().sqrt()
    ours_err = (ours - theirs[0]).pow(2).mean().sqrt()
    assert ours_err < 1.3 * noise, (float(ours_err), float(noise))
    assert abs(float(ours.mean() / theirs[0].mean()) - 1) < 0.01
    # a swapped tangent frame (alpha_x <-> alpha_y) is visibly different at this noise level
    swapped = _blocks(plugin.render(_scene(mi, {"type": "neumat", "material":
                                                "ggx:alpha_x=0.08,alpha_y=0.35,fresnel=none"}, 128, env)))
    assert (swapped - theirs[0]).pow(2).mean().sqrt() > 3 * noise


def test_model_file_through_load_dict(mi, tmp_path):
    model = NeuralAppearance(spatial_size=8)
    path = save_model(model, tmp_path / "model.nmat")
    bsdf = mi.load_dict({"type": "neumat", "material": str(path)})
    gen = torch.Generator().manual_seed(2)
    viewer, light = _random_dirs(500, gen, below=0.0), _random_dirs(500, gen, below=0.0)
    uv = torch.rand(500, 2, generator=gen)
    value = to_torch(bsdf.eval(mi.BSDFContext(), _interaction(mi, viewer, uv), mi_vector(mi, light)))
    with torch.no_grad():
        # not reciprocal: this pins the argument order (si.wi in the incident slot)
        expected = model.eval(Query(viewer, light, uv=uv)).double() * light[:, 2:3].double()
    assert torch.allclose(value, expected, rtol=1e-4, atol=1e-6)
    assert "neural" in str(bsdf)


def test_bad_input_is_refused_clearly(mi):
    import drjit as dr
    plugin = _plugin()
    with pytest.raises(Exception, match="'material' property"):
        mi.load_dict({"type": "neumat"})
    with pytest.raises(Exception, match="does not exist"):
        mi.load_dict({"type": "neumat", "material": "/no/such/model.nmat"})
    with pytest.raises(InputError, match="expected a neumat Material"):
        plugin.bsdf(42)
    from neumat.methods.neupress.model import NeuPreSS
    with pytest.raises(InputError, match="translucent"):
        plugin.bsdf(NeuPreSS())
    with pytest.raises(InputError, match="installed Mitsuba variants"):
        plugin.register("no_such_variant")
    with pytest.raises(InputError, match="unpolarised RGB variant"):
        plugin.register("scalar_spectral")
    assert mi.variant() == "llvm_ad_rgb"  # a refused variant is not set
    with pytest.raises(InputError, match="mitsuba Scene"):
        plugin.render("scene.xml")
    si = _interaction(mi, torch.tensor([[0.0, 0.0, 1.0]]), torch.zeros(1, 2))
    with pytest.raises(InputError, match="non-finite"):
        plugin.bsdf(_NaNs()).eval(mi.BSDFContext(), si, mi.Vector3f(0, 0, 1))
    # a symbolic scope holds no values torch could read: the active lanes get NaN, never a plausible value
    bsdf = plugin.bsdf(Lambert())
    si = dr.zeros(mi.SurfaceInteraction3f, 4)
    with dr.scoped_set_flag(dr.JitFlag.SymbolicScope, True):
        value = bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(0, 0, 1), mi.Bool([True, False, True, False]))
    assert np.array_equal(np.isnan(np.array(value)[0]), [True, False, True, False])


@pytest.mark.parametrize("rgl", ["paper_white_rgb", "vch_golden_yellow_rgb"])
def test_rgl_file_renders_like_mitsubas_measured(mi, shared_data, rgl):
    """The same table through the plugin and through Mitsuba's own `measured` plugin: the same argument order
    and the same importance sampling, so the same variance (each image's maximum, a firefly's height, within
    2x) and the same mean; before the plugin fed si.wi to the table's incident slot, paper_white rendered
    fireflies 1800x brighter than Mitsuba's maximum."""
    from neumat.reflectance.measured import RglMaterial
    plugin = _plugin()
    path = shared_data / "rgl" / f"{rgl}.bsdf"
    env = str(shared_data / "envmap" / "studio_small_03_1k.hdr")
    ours = plugin.render(_scene(mi, plugin.bsdf(RglMaterial.from_file(path)), 64, env, size=32))
    theirs = plugin.render(_scene(mi, {"type": "measured", "filename": str(path)}, 64, env, size=32))
    assert 0.5 < float(ours.max() / theirs.max()) < 2.0, (float(ours.max()), float(theirs.max()))
    assert abs(float(ours.mean() / theirs.mean()) - 1) < 0.01
    # the same random numbers through the same warps: the same image up to float error in almost every pixel
    close = ((ours - theirs).abs() <= 1e-3 * theirs.abs() + 1e-4).all(-1)
    assert float(close.float().mean()) > 0.99


def test_a_live_neumat_bsdf_leaves_other_scenes_unaffected(mi, shared_data):
    """Mitsuba's symbolic calls (plain `mi.render`) trace every live BSDF: a scene without a neumat BSDF
    renders the same image before and after one exists; a scene with one gets NaN where it is hit (no torch
    values exist in symbolic mode), not a plausible-looking wrong image."""
    import drjit as dr
    plugin = _plugin()
    env = str(shared_data / "envmap" / "studio_small_03_1k.hdr")
    conductor = {"type": "roughconductor", "distribution": "ggx", "alpha": 0.2}
    assert dr.flag(dr.JitFlag.SymbolicCalls)  # Mitsuba's default: symbolic virtual calls
    plain = _scene(mi, conductor, 4, env, size=16)
    before = np.array(mi.render(plain))
    live = plugin.bsdf(GGX(0.2))
    after = np.array(mi.render(plain))
    assert np.array_equal(before, after)
    with_neumat = np.array(mi.render(_scene(mi, live, 4, env, size=16)))
    assert np.isnan(with_neumat).any() and np.isfinite(with_neumat).any()
    assert bool(plugin.render(_scene(mi, live, 4, env, size=16)).isfinite().all())
