"""The NeuPreSS scene integrator (`neumat.integrations.mitsuba_translucent`): the object alone equals the standalone
render (subsurface of `render_translucent` plus the black-interior reflection trace) within Monte Carlo noise, other
objects render as plain volpath renders them, a rigid placement gives the same image, and misuse gives clear errors."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from neumat.core.errors import InputError

pytestmark = pytest.mark.mitsuba

RES = 32
BUNNY = "stanford_bunny_res4_453v.ply"


@pytest.fixture(scope="module")
def mi():
    from mitsuba_util import mitsuba_or_skip
    mitsuba_or_skip()
    from neumat.integrations import mitsuba_translucent as nt
    return nt.register()


def _nt():
    from neumat.integrations import mitsuba_translucent as nt
    return nt


def _model(lo, hi):
    """A tiny NeuPreSS with random weights (a positive S_hat of some structure) on the box lo - hi."""
    from neumat.methods.neupress.model import NeuPreSS
    torch.manual_seed(0)
    m = NeuPreSS(features=16, width=16, layers=2, sampler_hidden=(8,))
    m.set_bounds(torch.as_tensor(lo, dtype=torch.float32), torch.as_tensor(hi, dtype=torch.float32))
    with torch.no_grad():
        m.appearance.out.bias.add_(0.3)
    return m


def _env() -> np.ndarray:
    """A smooth (8, 16, 3) map, bright above (low noise at small spp)."""
    theta = (torch.arange(8) + 0.5) / 8
    phi = 2 * math.pi * (torch.arange(16) + 0.5) / 16
    img = torch.stack([1.5 - theta[:, None] + 0.3 * torch.cos(phi)[None],
                       1.0 + 0.5 * torch.sin(phi)[None].expand(8, 16), (0.6 + theta[:, None]).expand(8, 16)], -1)
    return img.numpy().astype(np.float32)


def _envmap(mi, env, to_world=None):
    """Mitsuba's envmap of `env` with each texel repeated 4 x 4 (nearest-texel radiance as EnvironmentMap)."""
    out = {"type": "envmap", "bitmap": mi.Bitmap(np.repeat(np.repeat(env, 4, 0), 4, 1))}
    if to_world is not None:
        out["to_world"] = to_world
    return out


def _sensor(mi, origin, target, up, fov=30.0):
    """A perspective sensor with the rays of neumat's pinhole camera (box pixel filter, vertical fov)."""
    return {"type": "perspective", "fov": fov, "fov_axis": "y",
            "to_world": mi.ScalarTransform4f().look_at(origin=list(map(float, origin)), target=list(map(float, target)),
                                                       up=list(map(float, up))),
            "film": {"type": "hdrfilm", "width": RES, "height": RES, "rfilter": {"type": "box"}}}


def _integrator(mi, model, config, strategy="mis", shape="translucent", **props):
    p = mi.Properties(_nt().PLUGIN_NAME)
    p["shape"] = shape
    p["strategy"] = strategy
    for k, v in props.items():
        p[k] = v
    return _nt()._integrator_class(mi)(p, model=model, source=config)


def _reflection(mi, config, env, camera, spp, seed):
    """The black-interior object's reflection along the pixel rays of `camera` (plain volpath, as the ground truth's
    "black" scene traces it)."""
    scene = mi.load_dict({"type": "scene", "integrator": {"type": "volpath", "max_depth": config.max_depth},
                          "object": _nt().translucent_shape(config), "light": _envmap(mi, env)})
    gen = torch.Generator().manual_seed(seed)
    pix = torch.arange(RES * RES)
    xy = torch.stack([pix % RES, pix // RES], -1).repeat_interleave(spp, 0).float()
    rays = camera.rays(xy + torch.rand(xy.shape, generator=gen))
    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(seed, xy.shape[0])
    ray = mi.Ray3f(mi.Point3f(*(mi.Float(c.contiguous()) for c in rays.o.float().T)),
                   mi.Vector3f(*(mi.Float(c.contiguous()) for c in rays.d.float().T)))
    value, _, _ = scene.integrator().sample(scene, sampler, ray)
    value = torch.from_numpy(np.array(value, dtype=np.float32).T.copy())
    return value.reshape(RES * RES, spp, 3).mean(1).reshape(RES, RES, 3)


def _agreement(a: list[torch.Tensor], b: list[torch.Tensor]) -> tuple[float, float]:
    """(mean squared difference of the two-seed means over its expectation from the seeds' spread, bias of the
    mean difference in standard deviations of that mean)."""
    d = (a[0] + a[1]) / 2 - (b[0] + b[1]) / 2
    var = ((a[0] - a[1]) ** 2 + (b[0] - b[1]) ** 2) / 4  # Var of each two-seed mean: (x0 - x1)^2 / 4
    return float((d ** 2).mean() / var.mean()), float(d.mean() / (var.sum().sqrt() / d.numel()))


@pytest.mark.parametrize("shape", ["sphere", "cube"])
def test_the_object_alone_matches_the_standalone_render(mi, shape):
    """The sphere, and the cube (the paperweight's outer shape: Mitsuba's cube, a mesh placed by its vertices)."""
    from neumat.reflectance.translucent import TranslucentConfig, TranslucentObject
    from neumat.render.lights import EnvironmentMap
    from neumat.render.translucent import orbit_camera, render_translucent
    nt = _nt()
    config, env = TranslucentConfig(shape=shape), _env()
    model = _model([-1.0] * 3, [1.0] * 3)
    obj = TranslucentObject(config, spp=1)
    camera = orbit_camera(obj, RES)
    scene = mi.load_dict({"type": "scene", "integrator": _integrator(mi, model, config),
                          "translucent": nt.translucent_shape(config), "light": _envmap(mi, env),
                          "sensor": _sensor(mi, camera.origin.tolist(), (0, 0, 0), (0, 1, 0))})
    spp = 16
    plugin = [nt.render(scene, spp=spp, seed=s)[..., :3] for s in (0, 1)]
    standalone = [render_translucent(model, obj, EnvironmentMap(env), camera, RES, spp=spp, seed=s)
                  + _reflection(mi, config, env, camera, spp, seed=10 + s) for s in (0, 1)]
    ratio, bias = _agreement(plugin, standalone)
    assert 0.5 < ratio < 1.4, ratio  # 0.86 measured: the difference is the noise
    assert abs(bias) < 4, bias
    # the subsurface term is there: without it the image is darker by far more than the noise
    inner = mi.load_dict({"type": "scene", "integrator": {"type": "volpath", "max_depth": config.max_depth},
                          "translucent": nt.translucent_shape(config), "light": _envmap(mi, env),
                          "sensor": _sensor(mi, camera.origin.tolist(), (0, 0, 0), (0, 1, 0))})
    assert _agreement(plugin, [nt.render(inner, spp=spp, seed=s)[..., :3] for s in (0, 1)])[0] > 10


def _box(mi, centre, size=0.6):
    return {"type": "cube", "to_world": mi.ScalarTransform4f().translate(list(centre)).scale(size),
            "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.2, 0.5, 0.8]}}}


def test_a_box_beside_the_object_renders_as_volpath_and_shadows_it(mi):
    from neumat.reflectance.translucent import TranslucentConfig
    nt = _nt()
    config, env = TranslucentConfig(), _env()
    model = _model([-1.0] * 3, [1.0] * 3)
    sensor = _sensor(mi, (0, 1.5, 7), (0.8, 0, 0), (0, 1, 0))

    def scene(integrator, box=True):
        d = {"type": "scene", "integrator": integrator, "translucent": nt.translucent_shape(config),
             "light": _envmap(mi, env), "sensor": sensor}
        if box:
            d["box"] = _box(mi, (1.9, 0.2, 0.3))
        return mi.load_dict(d)

    volpath = {"type": "volpath", "max_depth": config.max_depth}
    with_box = nt.render(scene(_integrator(mi, model, config, "light")), spp=8)[..., :3]
    plain = nt.render(scene(volpath), spp=8)[..., :3]
    no_box = nt.render(scene(_integrator(mi, model, config, "light"), box=False), spp=8)[..., :3]
    plain_no_box = nt.render(scene(volpath, box=False), spp=8)[..., :3]
    subsurface = with_box - plain  # the same random numbers: the inner integrator draws first
    on_object = subsurface.abs().amax(-1) > 0
    assert 50 < int(on_object.sum()) < RES * RES // 2
    assert torch.equal(with_box[~on_object], plain[~on_object])  # the box and the background: volpath's pixels
    assert float(subsurface.min()) > -1e-5
    # the box blocks part of the environment seen from the object: less subsurface light, by more than noise
    alone = (no_box - plain_no_box)[on_object]
    assert float(subsurface[on_object].mean()) < 0.97 * float(alone.mean())


def test_a_rigid_placement_gives_the_same_image(mi, shared_data):
    from neumat.reflectance.translucent import TranslucentConfig
    nt = _nt()
    config = TranslucentConfig(shape=str(shared_data / "mesh" / BUNNY))
    mesh = mi.load_dict({"type": "ply", "filename": config.shape})
    v = np.array(mi.traverse(mesh)["vertex_positions"], dtype=np.float64).reshape(-1, 3)
    lo, hi = v.min(0), v.max(0)
    model = _model(lo, hi)
    env = _env()
    centre = (lo + hi) / 2
    eye = centre + 3.5 * np.linalg.norm(hi - lo) * np.array([0.3, 0.4, 1.0]) / np.linalg.norm([0.3, 0.4, 1.0])
    axis = (np.array([1.0, 2.0, 3.0]) / math.sqrt(14)).tolist()  # Mitsuba's rotate takes a unit axis
    place = mi.ScalarTransform4f().translate([2.0, -1.0, 0.5]).rotate(axis, 50).scale(2.5)
    turn = mi.ScalarTransform4f().rotate(axis, 50)

    def render(to_world, eye, target, up, env_to_world, seed):
        s = mi.load_dict({"type": "scene", "integrator": _integrator(mi, model, config),
                          "translucent": nt.translucent_shape(config, to_world=to_world),
                          "light": _envmap(mi, env, env_to_world), "sensor": _sensor(mi, eye, target, up)})
        return nt.render(s, spp=8, seed=seed)[..., :3]

    base = [render(None, eye, centre, (0, 1, 0), None, seed) for seed in (0, 1)]
    moved = render(place, place @ mi.ScalarPoint3f(eye), place @ mi.ScalarPoint3f(centre),
                   turn @ mi.ScalarVector3f(0, 1, 0), turn, 0)
    noise = float(((base[0] - base[1]) ** 2).mean())
    assert float((base[0].abs().amax(-1) > 0).sum()) > 100
    # the same random numbers along rotated rays: equal up to float rounding, far below the noise
    assert float(((moved - base[0]) ** 2).mean()) < 0.02 * noise, (float(((moved - base[0]) ** 2).mean()), noise)


def test_misuse_gives_clear_errors(mi, shared_data):
    from neumat.reflectance.translucent import TranslucentConfig
    nt = _nt()
    config, env = TranslucentConfig(), _env()
    model = _model([-1.0] * 3, [1.0] * 3)
    sensor = _sensor(mi, (0, 0, 5), (0, 0, 0), (0, 1, 0))

    def render(shape, integrator=None):
        s = mi.load_dict({"type": "scene", "integrator": integrator or _integrator(mi, model, config),
                          "object": shape, "light": _envmap(mi, env), "sensor": sensor})
        return nt.render(s, spp=1)

    with pytest.raises(InputError, match="no shape with id 'translucent'"):
        render(nt.translucent_shape(config, shape_id="other"))
    with pytest.raises(InputError, match="fitted to another object"):
        render(nt.translucent_shape(config), _integrator(mi, _model([-1.0] * 3, [1.0, 1.0, 2.0]), config))
    sheared = mi.ScalarTransform4f().scale([1.0, 2.0, 1.0])
    with pytest.raises(InputError, match="non-uniform scale"):
        render(nt.translucent_shape(config, to_world=sheared))
    wrong_surface = {**nt.translucent_shape(config), "bsdf": {"type": "roughdielectric", "alpha": 0.1}}
    with pytest.raises(InputError, match="rough dielectric BSDF"):
        render(wrong_surface)
    bunny = TranslucentConfig(shape=str(shared_data / "mesh" / BUNNY))
    with pytest.raises(InputError, match="expected a sphere"):
        render(nt.translucent_shape(bunny, shape_id="translucent"))
    cube = {**nt.translucent_shape(config), "type": "cube"}
    cube.pop("radius")
    with pytest.raises(InputError, match="not the same mesh"):
        render(cube, _integrator(mi, model, bunny))
    with pytest.raises(InputError, match="expected the mesh 'cube'"):  # a cube's model, a sphere in the scene
        render(nt.translucent_shape(config), _integrator(mi, model, TranslucentConfig(shape="cube")))
    props = mi.Properties(nt.PLUGIN_NAME)
    props["shape"] = "translucent"
    with pytest.raises(InputError, match="'model' property is required"):
        nt._integrator_class(mi)(props, source=config)
    with pytest.raises(InputError, match="strategy"):
        _integrator(mi, model, config, strategy="best")
    with pytest.raises(InputError, match="NeuPreSS"):
        _integrator(mi, object(), config)
