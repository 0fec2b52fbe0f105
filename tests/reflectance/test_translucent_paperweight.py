"""The paperweight of NeuPreSS (TG et al., Table 1) in the translucent ground truth: an outer "cube", a homogeneous
outer medium (`outer_medium`, `outer_density`) with the noise mix inside an inner shape, the preset and its
errors."""
import math

import numpy as np
import pytest
import torch

from neumat import InputError
from tests.mitsuba_util import mitsuba_or_skip

pytestmark = pytest.mark.mitsuba


def _object(spp=64, seed=0, **kw):
    mitsuba_or_skip()
    from neumat.reflectance.translucent import TranslucentConfig, TranslucentObject
    return TranslucentObject(TranslucentConfig(**kw), spp=spp, seed=seed)


def _rays_down(n, x=0.0, y=0.0):
    o = torch.tensor([[x, y, 3.0]], dtype=torch.float64).expand(n, 3).contiguous()
    d = torch.tensor([[0.0, 0.0, -1.0]], dtype=torch.float64).expand(n, 3).contiguous()
    return o, d


def _octahedron(path, scale=1.0, offset=(0.0, 0.0, 0.0)):
    """A closed ASCII PLY octahedron with outward-wound faces."""
    v = scale * np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], dtype=float)
    v = v + np.array(offset)
    faces = [(0, 2, 4), (2, 1, 4), (1, 3, 4), (3, 0, 4), (2, 0, 5), (1, 2, 5), (3, 1, 5), (0, 3, 5)]
    head = ("ply\nformat ascii 1.0\nelement vertex 6\nproperty float x\nproperty float y\nproperty float z\n"
            "element face 8\nproperty list uchar int vertex_indices\nend_header\n")
    path.write_text(head + "".join(f"{a} {b} {c}\n" for a, b, c in v)
                    + "".join(f"3 {a} {b} {c}\n" for a, b, c in faces))
    return path


def test_cube_geometry():
    """Mitsuba's cube is [-1, 1]^3: rays down hit the top face at z = 1 with normal +z, rays beside it miss, its
    area is 24 and its samples lie on the faces; eval takes points of the top face and refuses points inside."""
    obj = _object(shape="cube")
    assert np.allclose(obj.bbox_min, -1) and np.allclose(obj.bbox_max, 1)
    assert math.isclose(obj.diagonal, 2 * math.sqrt(3), rel_tol=1e-6)
    o = torch.tensor([[0.5, 0.2, 3.0], [-0.9, 0.9, 3.0], [1.5, 0.0, 3.0]], dtype=torch.float64)
    d = torch.tensor([[0.0, 0.0, -1.0]], dtype=torch.float64).expand(3, 3)
    hit, x, n = obj.first_hits(o, d)
    assert hit.tolist() == [True, True, False]
    assert torch.allclose(x, torch.tensor([[0.5, 0.2, 1.0], [-0.9, 0.9, 1.0]], dtype=torch.float64), atol=1e-5)
    assert torch.allclose(n, torch.tensor([[0.0, 0.0, 1.0]] * 2, dtype=torch.float64), atol=1e-6)
    p, normal, area = obj.surface_samples(2000)
    assert math.isclose(float(area.sum()), 24.0, rel_tol=1e-4)
    assert torch.allclose(p.abs().max(-1).values, torch.ones(2000, dtype=torch.float64), atol=1e-5)
    assert torch.allclose(normal.abs().max(-1).values, torch.ones(2000, dtype=torch.float64), atol=1e-5)
    from neumat.core.query import Query
    top = torch.tensor([[0.2, 0.3, 1.0]])
    f = obj.eval(Query(wi=torch.tensor([[0.0, 0.0, 1.0]]), wo=torch.tensor([[0.0, 0.0, 1.0]]), x=top))
    assert f.shape == (1, 3) and bool((f > 0).all())
    with pytest.raises(InputError, match="not on the surface"):
        obj.surface(torch.tensor([[0.2, 0.3, 0.5]]), torch.tensor([[0.0, 0.0, 1.0]]))


def test_inner_cube_is_placed_by_center_and_scale():
    obj = _object(inner=[{"shape": "cube", "center": [0.1, 0.0, 0.0], "scale": 0.3, "albedo": [0, 0, 0]}])
    box = [s for s in obj.scenes["medium"].shapes() if s.bbox().max[0] < 0.9][0].bbox()
    assert np.allclose(box.min, [-0.2, -0.3, -0.3], atol=1e-6) and np.allclose(box.max, [0.4, 0.3, 0.3], atol=1e-6)
    with pytest.raises(InputError, match="not inside"):
        _object(shape="cube", inner=[{"shape": "cube", "center": [0.9, 0, 0], "scale": 0.3}])


def test_homogeneous_outer_medium_equals_the_noise_mix_of_one_medium():
    """outer_medium M is the same volume as the noise mixing M with itself (a constant grid): S_hat through the
    cube agrees within 4 standard errors (independent paths); ketchup in its place is told apart."""
    o, d = _rays_down(64, x=0.3)
    light = torch.tensor([0.0, 0.6, -0.8], dtype=torch.float64)
    a = _object(shape="cube", size_mm=2.0, spp=128, outer_medium="skin1").trace(o, d, light)
    b = _object(shape="cube", size_mm=2.0, spp=128, seed=1, media=("skin1", "skin1")).trace(o, d, light)
    se = ((a.var(0) + b.var(0)) / 64).sqrt()
    assert bool(((a.mean(0) - b.mean(0)).abs() < 4 * se).all()), (a.mean(0), b.mean(0), se)
    c = _object(shape="cube", size_mm=2.0, spp=128, outer_medium="ketchup").trace(o, d, light)
    assert bool(((a.mean(0) - c.mean(0)).abs() > 4 * se).any()), (a.mean(0), c.mean(0), se)


def test_outer_density_scales_the_medium_as_the_size_does():
    """Halving the density of the outer medium is halving the object's size in millimetres (no inner shapes):
    the same medium, so the same random numbers give the same values."""
    o, d = _rays_down(16, x=0.2)
    light = torch.tensor([0.0, 0.6, -0.8], dtype=torch.float64)
    half = _object(shape="cube", size_mm=2.0, spp=16, outer_medium="skimmilk", outer_density=0.5).trace(o, d, light)
    small = _object(shape="cube", size_mm=1.0, spp=16, outer_medium="skimmilk").trace(o, d, light)
    assert torch.equal(half, small)
    thick = _object(shape="cube", size_mm=2.0, spp=16, outer_medium="skimmilk").trace(o, d, light)
    assert not torch.equal(half, thick)


def test_black_ink_outer_medium_leaves_only_the_inner_shape_dark():
    """An inner sphere of the noise mix in an outer medium of black ink (absorbing, not scattering): S_hat is ~0
    (nothing gets through the ink), while the same sphere in the noise mix (no outer_medium) is lit."""
    from neumat.reflectance import translucent
    with pytest.MonkeyPatch.context() as mp:
        mp.setitem(translucent.JENSEN_MEDIA, "ink", ((1e-4, 1e-4, 1e-4), (50.0, 50.0, 50.0)))
        inner = [{"scale": 0.5, "medium": "noise"}]
        o, d = _rays_down(8, x=0.1)
        light = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
        ink = _object(shape="cube", spp=64, outer_medium="ink", inner=inner)
        kinds = sorted(str(s.interior_medium()).split("[")[0] for s in ink.scenes["medium"].shapes())
        assert kinds == ["HeterogeneousMedium", "HomogeneousMedium"], kinds  # the noise is inside, the ink outside
        assert float(ink.trace(o, d, light).abs().max()) < 1e-3
        plain = _object(shape="cube", spp=64, inner=inner).trace(o, d, light)
        assert float(plain.mean(0).min()) > 0.01


def test_old_source_dicts_without_the_new_fields_load_as_before():
    from neumat.core.config import config_from_dict, config_to_dict
    from neumat.reflectance.translucent import TranslucentConfig
    old = {k: v for k, v in config_to_dict(TranslucentConfig()).items() if k not in ("outer_medium", "outer_density")}
    assert config_from_dict(TranslucentConfig, old) == TranslucentConfig()


@pytest.mark.parametrize("kw, match", [
    (dict(shape="cone"), "expected 'sphere', 'cube'"),
    (dict(inner=[{"shape": "cone"}]), "inner\\[0\\] shape"),
    (dict(outer_medium="jam"), "outer_medium"),
    (dict(outer_medium="skimmilk", outer_density=0.0), "outer_density"),
    (dict(outer_medium="skimmilk", outer_density=float("nan")), "outer_density"),
    (dict(outer_density=0.5), "outer_density: scales a homogeneous outer_medium"),
])
def test_bad_paperweight_config(kw, match):
    with pytest.raises(InputError, match=match):
        _object(**kw)


def test_paperweight_preset_centres_and_fits_its_mesh(tmp_path):
    mitsuba_or_skip()
    from neumat.reflectance.translucent import TranslucentObject, paperweight_config
    mesh = _octahedron(tmp_path / "b.ply", scale=0.05, offset=(0.3, 0.1, -0.2))
    cfg = paperweight_config(mesh)
    assert cfg.shape == "cube" and cfg.outer_medium == "skimmilk" and cfg.outer_density == 0.05
    assert len(cfg.inner) == 1 and cfg.inner[0].medium == "noise" and cfg.inner[0].ior is None
    obj = TranslucentObject(cfg, spp=1)
    inner = [s for s in obj.scenes["medium"].shapes() if s.bbox().max[0] < 0.99][0].bbox()
    assert np.allclose(inner.min, -0.7, atol=1e-5) and np.allclose(inner.max, 0.7, atol=1e-5)
    with pytest.raises(InputError, match="does not exist"):
        paperweight_config(tmp_path / "none.ply")
    with pytest.raises(InputError, match="fill"):
        paperweight_config(mesh, fill=1.2)


def test_paperweight_scene_on_the_command_line(tmp_path, monkeypatch):
    """`trace --scene paperweight` takes the bunny from the reference data (here a stand-in octahedron) and lets
    the other options change the preset's fields."""
    mitsuba_or_skip()
    from typer.testing import CliRunner

    from neumat.cli.main import app
    from neumat.fit.translucent_observations import Observations
    (tmp_path / "data" / "mesh").mkdir(parents=True)
    _octahedron(tmp_path / "data" / "mesh" / "stanford_bunny_35k.ply", scale=0.1)
    monkeypatch.setenv("NEUMAT_SHARED_DATA", str(tmp_path / "data"))
    r = CliRunner().invoke(app, ["translucent", "trace", "--scene", "paperweight", "-o", str(tmp_path / "o.npz"),
                                 "--images", "2", "--resolution", "8", "--spp", "2", "--noise-check", "0", "-q",
                                 "--size-mm", "3"])
    assert r.exit_code == 0, r.output
    cfg = Observations.load_source(tmp_path / "o.npz")["object"]
    assert cfg["shape"] == "cube" and cfg["outer_medium"] == "skimmilk" and cfg["size_mm"] == 3.0
    assert cfg["inner"][0]["medium"] == "noise" and cfg["media"] == ["marble", "skin1"]
    r = CliRunner().invoke(app, ["translucent", "trace", "--scene", "cone", "-o", str(tmp_path / "p.npz")])
    assert r.exit_code == 2 and "paperweight" in "".join(r.output.split())
