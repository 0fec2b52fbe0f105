"""The paper's scenes in the translucent ground truth: inner shapes (their own media or opaque diffuse surfaces),
a roughness texture on the surface, an albedo texture on the medium, and the noise estimate of observations."""
import math

import numpy as np
import pytest
import torch

from neumat import InputError
from neumat.core.query import Query
from neumat.io.images import write_image
from tests.mitsuba_util import mitsuba_or_skip

pytestmark = pytest.mark.mitsuba

BACKLIT = torch.tensor([0.0, 0.0, -1.0], dtype=torch.float64)  # light arriving from below


def _object(spp=64, seed=0, **kw):
    mitsuba_or_skip()
    from neumat.reflectance.translucent import TranslucentConfig, TranslucentObject
    return TranslucentObject(TranslucentConfig(**kw), spp=spp, seed=seed)


def _rays_down(n, x=0.0):
    o = torch.tensor([[x, 0.0, 3.0]], dtype=torch.float64).expand(n, 3).contiguous()
    d = torch.tensor([[0.0, 0.0, -1.0]], dtype=torch.float64).expand(n, 3).contiguous()
    return o, d


def _octahedron(path, scale=1.0):
    """A closed ASCII PLY octahedron with outward-wound faces, no uv."""
    v = scale * np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], dtype=float)
    faces = [(0, 2, 4), (2, 1, 4), (1, 3, 4), (3, 0, 4), (2, 0, 5), (1, 2, 5), (3, 1, 5), (0, 3, 5)]
    head = ("ply\nformat ascii 1.0\nelement vertex 6\nproperty float x\nproperty float y\nproperty float z\n"
            "element face 8\nproperty list uchar int vertex_indices\nend_header\n")
    path.write_text(head + "".join(f"{a} {b} {c}\n" for a, b, c in v)
                    + "".join(f"3 {a} {b} {c}\n" for a, b, c in faces))
    return path


def test_black_inner_sphere_blocks_the_light_through_the_object():
    """Backlit, seen from above: most of S_hat is light crossing the object; a black diffuse core stops it."""
    o, d = _rays_down(8)
    clear = _object(size_mm=2.0, spp=256).trace(o, d, BACKLIT).mean(0)
    core = _object(size_mm=2.0, spp=256, inner=[{"scale": 0.6, "albedo": [0, 0, 0]}]).trace(o, d, BACKLIT).mean(0)
    assert bool((core < 0.05 * clear).all()), (core, clear)


def test_index_matched_inner_copy_of_the_medium_changes_nothing():
    """An inner sphere holding the outer medium behind a null interface is no boundary at all: S_hat agrees
    within 4 standard errors (64 rays, independent paths), where a black core of that size is told apart."""
    o, d = _rays_down(64, x=0.3)
    light = torch.tensor([0.0, 0.6, -0.8], dtype=torch.float64)
    a = _object(size_mm=2.0, spp=128).trace(o, d, light)
    b = _object(size_mm=2.0, spp=128, seed=1, inner=[{"scale": 0.6, "medium": "noise"}]).trace(o, d, light)
    se = ((a.var(0) + b.var(0)) / 64).sqrt()
    assert bool(((a.mean(0) - b.mean(0)).abs() < 4 * se).all()), (a.mean(0), b.mean(0), se)
    c = _object(size_mm=2.0, spp=128, inner=[{"scale": 0.6, "albedo": [0, 0, 0]}]).trace(o, d, light)
    assert bool(((a.mean(0) - c.mean(0)).abs() > 4 * se).all())  # the comparison sees a black core there


def test_surface_queries_see_only_the_outer_surface():
    obj = _object(inner=[{"scale": 0.5, "albedo": [0.2, 0.3, 0.4]}])
    o, d = _rays_down(3)
    hit, x, n = obj.first_hits(o, d)
    assert hit.all() and torch.allclose(x.norm(dim=-1), torch.ones(3, dtype=torch.float64), atol=1e-5)
    with pytest.raises(InputError, match="not on the surface"):
        obj.surface(torch.tensor([[0.0, 0.0, 0.5]]), torch.tensor([[0.0, 0.0, 1.0]]))
    assert len(obj.scenes["black"].shapes()) == 1 and len(obj.scenes["medium"].shapes()) == 2


def test_textured_inner_albedo_uses_the_image(tmp_path):
    """A zero image gives exactly the black constant albedo's result (same random numbers)."""
    write_image(tmp_path / "zero.exr", np.zeros((4, 8, 3), np.float32))
    o, d = _rays_down(8)
    black = _object(size_mm=2.0, spp=16, inner=[{"scale": 0.6, "albedo": [0, 0, 0]}]).trace(o, d, BACKLIT)
    image = _object(size_mm=2.0, spp=16, inner=[{"scale": 0.6, "albedo_texture": str(tmp_path / "zero.exr")}])
    assert torch.equal(image.trace(o, d, BACKLIT), black)


def test_roughness_texture_sets_the_surface_alpha(tmp_path):
    """External reflection at normal incidence is F(0) / (4 pi alpha^2): at random points of the sphere, lit and
    seen along the normal, Mitsuba's alpha is what `surface_roughness` reads from the texture."""
    rng = np.random.default_rng(0)
    write_image(tmp_path / "r.exr", rng.uniform(size=(6, 10, 3)).astype(np.float32))
    ior = 1.5
    obj = _object(roughness_texture=str(tmp_path / "r.exr"), roughness_range=(0.1, 0.4), ior=ior)
    x = torch.nn.functional.normalize(torch.randn(5, 3, generator=torch.Generator().manual_seed(1),
                                                  dtype=torch.float64), dim=-1)
    alpha = obj.surface_roughness(x)
    assert alpha.shape == (5,) and alpha.dtype == torch.float64 and float(alpha.std()) > 0.02
    f0 = ((ior - 1) / (ior + 1)) ** 2
    for k in range(5):
        obj._set_light(x[k])
        value = obj._radiance("black", 2 * x[k:k + 1], -x[k:k + 1], seed=0)
        assert torch.allclose(value, torch.full_like(value, f0 / (4 * math.pi * float(alpha[k]) ** 2)), rtol=1e-3)
    assert torch.equal(_object(roughness=0.25).surface_roughness(x), torch.full((5,), 0.25, dtype=torch.float64))


def test_constant_roughness_texture_equals_the_scalar_roughness(tmp_path):
    write_image(tmp_path / "c.exr", np.full((4, 8, 3), 0.5, np.float32))
    o, d = _rays_down(32, x=0.3)
    light = torch.tensor([0.0, 0.6, 0.8], dtype=torch.float64)
    scalar = _object(size_mm=2.0, spp=8, roughness=0.3).trace(o, d, light)
    texture = _object(size_mm=2.0, spp=8, roughness_texture=str(tmp_path / "c.exr"), roughness_range=(0.1, 0.5))
    assert torch.allclose(texture.trace(o, d, light), scalar, rtol=1e-5, atol=1e-6)  # float32 interpolation only


def test_roughness_texture_on_a_mesh_is_per_vertex(tmp_path):
    write_image(tmp_path / "r.exr", np.random.default_rng(0).uniform(size=(6, 10, 3)).astype(np.float32))
    obj = _object(shape=str(_octahedron(tmp_path / "o.ply")), roughness_texture=str(tmp_path / "r.exr"))
    mesh = obj.scenes["medium"].shapes()[0]
    vertices = torch.from_numpy(np.array(mesh.vertex_positions_buffer(), dtype=np.float64).reshape(-1, 3))
    stored = np.array(mesh.attribute_buffer("vertex_alpha"), dtype=np.float64)
    assert np.allclose(obj.surface_roughness(vertices).numpy(), stored, rtol=1e-6)
    assert obj.scenes["black"].shapes()[0].has_attribute("vertex_alpha")  # the black scene reflects the same


def test_albedo_texture_multiplies_the_medium_albedo(tmp_path):
    from neumat.reflectance.translucent import TranslucentConfig, medium_grids
    lo, hi = np.array([-1.0] * 3), np.array([1.0] * 3)
    plain = medium_grids(TranslucentConfig(grid_resolution=8), lo, hi)
    write_image(tmp_path / "one.exr", np.ones((4, 8, 3), np.float32))
    ones = medium_grids(TranslucentConfig(grid_resolution=8, albedo_texture=str(tmp_path / "one.exr")), lo, hi)
    assert np.array_equal(ones[0], plain[0]) and np.array_equal(ones[1], plain[1])
    half = np.full((4, 8, 3), 0.5, np.float32)
    half[:, :, 2] = 0.25
    write_image(tmp_path / "half.exr", half)
    tinted = medium_grids(TranslucentConfig(grid_resolution=8, albedo_texture=str(tmp_path / "half.exr")), lo, hi)
    assert np.array_equal(tinted[0], plain[0])
    assert np.allclose(tinted[1], plain[1] * np.array([0.5, 0.5, 0.25]), rtol=1e-6)


def test_noise_variance_is_half_the_squared_difference_of_two_evaluations():
    x = torch.nn.functional.normalize(torch.tensor([[0.2, 0.1, 1.0], [0.1, -0.3, 1.0]]), dim=-1)
    q = Query(wi=torch.tensor([[0.0, 0.6, 0.8]]).expand(2, 3), wo=x, x=x)
    a = _object(spp=4)
    variance = a.noise_variance(q)
    b = _object(spp=4)
    first, second = b.eval(q).double(), b.eval(q).double()
    assert variance.shape == (2, 3) and bool((variance > 0).any())
    assert torch.allclose(variance, (first - second) ** 2 / 2)


@pytest.mark.parametrize("kw, match", [
    (dict(inner=[{"center": [0.9, 0, 0], "scale": 0.3}]), "not inside"),
    (dict(inner=[{"scale": 0.3, "center": [0.2, 0, 0]}, {"scale": 0.3, "center": [-0.2, 0, 0]}]), "overlaps"),
    (dict(inner=[{"medium": "jam"}]), "medium"),
    (dict(inner=[{"ior": 1.3}]), "opaque"),
    (dict(inner=[{"albedo": [1.5, 0, 0]}]), "albedo"),
    (dict(inner=[{"medium": "marble", "albedo_texture": "x.png"}]), "albedo_texture"),
    (dict(inner=[{"shape": "/no/such.ply"}]), "shape"),
    (dict(inner=[{"radius": 0.3}]), "unknown key"),
    (dict(inner=[{"scale": 0.0}]), "scale"),
    (dict(roughness_texture="/no/such.png"), "does not exist"),
    (dict(albedo_texture="/no/such.exr"), "does not exist"),
    (dict(roughness_range=(0.0, 0.5)), "roughness_range"),
    (dict(interior_emitter_sampling="no"), "interior_emitter_sampling"),
    (dict(interior_emitter_sampling=1), "interior_emitter_sampling"),
    (dict(rr_depth=0), "rr_depth"),
    (dict(sampler="sobol"), "sampler"),
])
def test_bad_scene_config(kw, match):
    with pytest.raises(InputError, match=match):
        _object(**kw)


def test_mesh_albedo_texture_needs_uv(tmp_path):
    write_image(tmp_path / "a.exr", np.ones((2, 2, 3), np.float32))
    mesh = _octahedron(tmp_path / "o.ply", scale=0.3)
    with pytest.raises(InputError, match="uv"):
        _object(inner=[{"shape": str(mesh), "albedo_texture": str(tmp_path / "a.exr")}])


def test_estimator_defaults_and_old_descriptions():
    """An object description written before issue 51's estimator fields existed (no `interior_emitter_sampling`,
    `rr_depth`) loads with the defaults, False and 20 (same mean, `test_translucent.
    test_default_estimator_keeps_the_mean`); a JSON boolean is kept, anything else refused."""
    from neumat.core.config import config_from_dict
    from neumat.reflectance.translucent import TranslucentConfig
    old = {"shape": "sphere", "media": ["marble", "ketchup"], "size_mm": 4.0, "max_depth": 5000}
    assert config_from_dict(TranslucentConfig, old).interior_emitter_sampling is False
    assert config_from_dict(TranslucentConfig, old).rr_depth == 20
    assert config_from_dict(TranslucentConfig, {**old, "interior_emitter_sampling": True}).interior_emitter_sampling
    with pytest.raises(InputError, match="interior_emitter_sampling"):
        config_from_dict(TranslucentConfig, {**old, "interior_emitter_sampling": "yes"})
