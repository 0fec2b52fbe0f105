"""Mitsuba 3 integrator plugin that puts a NeuPreSS translucent object (a model of `neumat fit OBS.npz --model neupress`) in a
Mitsuba scene with other objects and lights.

`register()` adds the integrator "neumat_translucent", `translucent_shape(observations, to_world=T)` places
the object, `render(scene, spp)` renders (evaluated mode). The inner integrator renders the object's rough
dielectric surface; the plugin adds the learned subsurface term under distant light (TG et al., Eq. 5).

Details: docs/formats/mitsuba_plugins.md, section `neumat.integrations.mitsuba_translucent`.
"""
from __future__ import annotations

import functools
from pathlib import Path

import numpy as np
import torch

from ..core.errors import InputError
from ..core.query import Query
from . import mitsuba as bsdf_plugin

#: the integrator name registered with Mitsuba
PLUGIN_NAME = "neumat_translucent"
#: subsurface estimators: MIS of both, emitter sampling alone, the model's lobe alone
STRATEGIES = ("mis", "light", "model")
#: the black interior of the object (as the ground truth's "black" scene)
BLACK_MEDIUM = {"type": "homogeneous", "albedo": 0.0, "sigma_t": 1e6}
#: tolerance (fraction of the object's diagonal) of the vertex fit and of the model's box against the object's
PLACEMENT_TOLERANCE = 1e-4
#: most passes through the object's own surface when tracing from its centre
SELF_PASSES = 16
_DTYPE = torch.float32


def register(variant: str | None = None):
    """Register the "neumat_translucent" integrator (and the "neumat" BSDF) and return the `mitsuba` module;
    variant as in `neumat.integrations.mitsuba.register`."""
    mi = bsdf_plugin.register(variant)
    cls = _integrator_class(mi)
    mi.register_integrator(PLUGIN_NAME, lambda props: cls(props))
    return mi


def render(scene, spp: int | None = None, seed: int = 0, sensor: int = 0) -> torch.Tensor:
    """`neumat.integrations.mitsuba.render`: the scene in evaluated mode, (H, W, C) float32 linear RGB."""
    return bsdf_plugin.render(scene, spp=spp, seed=seed, sensor=sensor)


def object_config(source):
    """The `TranslucentConfig` of `source`: an observations file of `neumat translucent trace` (its saved object),
    a TranslucentConfig, or a dict of its fields."""
    from ..core.config import config_from_dict
    from ..reflectance.translucent import TranslucentConfig
    if isinstance(source, TranslucentConfig):
        return source
    if isinstance(source, dict):
        return config_from_dict(TranslucentConfig, source)
    if isinstance(source, (str, Path)):
        from ..fit.translucent_observations import Observations
        saved = Observations.load_source(source)
        if saved is None or "object" not in saved:
            raise InputError(f"observations {str(source)!r}: no object description (write it with "
                             "`neumat translucent trace`)")
        return config_from_dict(TranslucentConfig, saved["object"])
    raise InputError(f"translucent object: expected an observations file, a TranslucentConfig or a dict, got "
                     f"{type(source).__name__}")


def translucent_shape(source, to_world=None, shape_id: str = "translucent") -> dict:
    """The `mi.load_dict` entry of the object of `source` (see `object_config`): its outer surface ("sphere": the
    unit sphere, or the PLY mesh) with the rough dielectric of its config (GGX alpha, ior) and a black interior,
    placed by `to_world` (a `mi.ScalarTransform4f`, a 4 x 4 matrix, or None), with id `shape_id` (what the
    integrator's "shape" names)."""
    cfg = object_config(source)
    mi = bsdf_plugin._current_mitsuba()
    shape = {"type": "sphere", "radius": 1.0} if cfg.shape == "sphere" else {"type": "ply", "filename": str(cfg.shape)}
    shape.update(id=shape_id, interior=dict(BLACK_MEDIUM),
                 bsdf={"type": "roughdielectric", "distribution": "ggx", "alpha": cfg.roughness,
                       "int_ior": cfg.ior, "ext_ior": 1.0})
    if to_world is not None:
        shape["to_world"] = to_world if isinstance(to_world, mi.ScalarTransform4f) else \
            mi.ScalarTransform4f(np.asarray(to_world, dtype=np.float64).tolist())
    return shape


def similarity(matrix: np.ndarray, what: str) -> tuple[np.ndarray, float, np.ndarray]:
    """(R (3, 3) rotation, s uniform scale, t (3,)) of a 4 x 4 object-to-world matrix; InputError naming `what`
    when it is not rotation * uniform scale + translation."""
    m = np.asarray(matrix, dtype=np.float64)
    a, t = m[:3, :3], m[:3, 3]
    det = float(np.linalg.det(a))
    if not (np.isfinite(m).all() and det > 0 and np.allclose(m[3], [0, 0, 0, 1], atol=1e-6)):
        raise InputError(f"{what}: its to_world must be a rotation, a uniform scale and a translation "
                         f"(no mirroring or projection), got {np.round(m, 6).tolist()}")
    s = det ** (1 / 3)
    r = a / s
    if not np.allclose(r.T @ r, np.eye(3), atol=1e-4):
        raise InputError(f"{what}: its to_world has shear or a non-uniform scale (singular values "
                         f"{np.round(np.linalg.svd(a, compute_uv=False), 6).tolist()}); the learned S_hat only holds "
                         "under rotation, uniform scale and translation")
    return r, s, t


def _integrator_class(mi) -> type:
    """The plugin class for mi's current variant, built once per variant (Mitsuba's base classes differ per
    variant)."""
    return _integrator_class_of(mi.variant())


@functools.cache
def _integrator_class_of(variant: str) -> type:
    import mitsuba as mi

    return _make_integrator_class(mi)


def _make_integrator_class(mi) -> type:
    import drjit as dr

    class NeumatTranslucentIntegrator(mi.SamplingIntegrator):
        """The inner integrator plus NeuPreSS subsurface radiance at camera hits on one shape (module docstring).

        Properties: integrator (nested, default volpath with max_depth), shape (the object's id), model (.nmat of
        a NeuPreSS), observations (its observations file: the object's config), strategy (mis | light | model),
        samples (subsurface samples per camera sample and strategy, default 1)."""

        def __init__(self, props, model=None, source=None):
            mi.SamplingIntegrator.__init__(self, props)
            inner = props.get("integrator", None) if "integrator" in props else None
            if inner is None:
                spec = {"type": "volpath"}
                if "max_depth" in props:
                    spec["max_depth"] = props["max_depth"]
                inner = mi.load_dict(spec)
            elif not isinstance(inner, mi.SamplingIntegrator):
                raise InputError(f"{PLUGIN_NAME}: 'integrator' must be a sampling integrator (path, volpath, ...), "
                                 f"got {type(inner).__name__}")
            self.inner = inner
            for key in ("shape",) + (() if model is not None else ("model",)) + \
                    (() if source is not None else ("observations",)):
                if key not in props:
                    raise InputError(f"{PLUGIN_NAME}: the '{key}' property is required (shape: the translucent "
                                     "shape's id; model: its NeuPreSS .nmat; observations: the observations file "
                                     "it was fitted to, which names the object)")
            self.shape_id = str(props["shape"])
            self.strategy = str(props.get("strategy", "mis"))
            if self.strategy not in STRATEGIES:
                raise InputError(f"{PLUGIN_NAME}: strategy: expected one of {STRATEGIES}, got {self.strategy!r}")
            self.samples = int(props.get("samples", 1))
            if self.samples < 1:
                raise InputError(f"{PLUGIN_NAME}: samples: expected a positive integer, got {self.samples}")
            self.model = _open_model(props["model"] if model is None else model)
            self.config = object_config(props["observations"] if source is None else source)
            self._object_vertices = None

        def aov_names(self):
            return self.inner.aov_names()

        def to_string(self):
            return f"NeumatTranslucent[shape={self.shape_id!r}, strategy={self.strategy!r}, inner={self.inner}]"

        def sample(self, scene, sampler, ray, medium=None, active=True):
            result = self.inner.sample(scene, sampler, ray, medium, active)
            if bsdf_plugin._symbolic(dr):
                return result
            L, valid, aovs = result
            shape, place = self._placement(scene)
            n = dr.width((ray.o, ray.d, active))
            si = scene.ray_intersect(mi.Ray3f(ray), active)
            on = si.is_valid() & (si.shape == mi.ShapePtr(shape)) & active
            rows = torch.from_numpy(np.array(dr.zeros(mi.Bool, n) | on, dtype=bool)).nonzero().squeeze(1)
            total = torch.zeros(n, 3, dtype=_DTYPE)
            if rows.numel():
                x_w = bsdf_plugin._vec(si.p, n)[rows].double()
                n_w = bsdf_plugin._vec(si.n, n)[rows].double()
                wo_w = -bsdf_plugin._vec(ray.d, n)[rows].double()
                r, s, t, centre = place
                x_o = ((x_w - t) @ r) / s   # rows of R^T (x - t) / s
                n_o, wo_o = _unit(n_w @ r), _unit(wo_w @ r)
                for _ in range(self.samples):
                    total[rows] += self._subsurface(scene, shape, sampler, n, rows, x_o, n_o, wo_o, r, centre)
                total /= self.samples
            return L + bsdf_plugin._color(mi, total), valid, aovs

        # ---- placement ----------------------------------------------------------------------------------
        def _placement(self, scene):
            """(the shape, (R (3, 3), s, t (3,), centre (3,) world, all float64 torch))."""
            shapes = {sh.id(): sh for sh in scene.shapes()}
            if self.shape_id not in shapes:
                raise InputError(f"{PLUGIN_NAME}: the scene has no shape with id {self.shape_id!r} (ids: "
                                 f"{sorted(shapes)})")
            shape = shapes[self.shape_id]
            what = f"shape {self.shape_id!r}"
            params = mi.traverse(shape)
            if self.config.shape == "sphere":
                if "to_world" not in params:
                    raise InputError(f"{what}: expected a sphere (the object of the observations is the unit "
                                     f"sphere), got a {type(shape).__name__} (no to_world)")
                matrix = np.array(params["to_world"].matrix, dtype=np.float64).reshape(4, 4)
            else:
                if "vertex_positions" not in params:
                    raise InputError(f"{what}: expected the mesh {self.config.shape!r} of the observations, got a "
                                     f"{type(shape).__name__} that is not a mesh")
                matrix = self._mesh_transform(np.array(params["vertex_positions"], dtype=np.float64).reshape(-1, 3),
                                              what)
            r, s, t = similarity(matrix, what)
            self._check_surface(shape, params, what)
            lo, hi = self._object_box()
            model_lo = self.model.box_min.detach().double().cpu().numpy()
            model_hi = self.model.box_max.detach().double().cpu().numpy()
            diagonal = float(np.linalg.norm(hi - lo))
            if max(np.abs(model_lo - lo).max(), np.abs(model_hi - hi).max()) > 1e-3 * diagonal:
                raise InputError(f"{PLUGIN_NAME}: the model's object-space box {np.round(model_lo, 4).tolist()} - "
                                 f"{np.round(model_hi, 4).tolist()} is not the box of the observations' object "
                                 f"{np.round(lo, 4).tolist()} - {np.round(hi, 4).tolist()}: the model was fitted to "
                                 "another object (or placed elsewhere)")
            centre = t + s * (r @ ((lo + hi) / 2))
            as_t = [torch.from_numpy(np.asarray(v, dtype=np.float64)) for v in (r, s, t, centre)]
            return shape, tuple(as_t)

        def _check_surface(self, shape, params, what):
            """The shape must carry the object's rough dielectric (the model excludes that reflection) and an
            interior medium (black, so that the inner integrator renders the reflection alone)."""
            cfg = self.config
            alpha = np.array(params["bsdf.alpha.value"]).ravel() if "bsdf.alpha.value" in params else None
            eta = np.array(params["bsdf.eta"]).ravel() if "bsdf.eta" in params else None
            if (not str(shape.bsdf()).startswith("RoughDielectric") or alpha is None or eta is None
                    or not np.allclose(alpha, cfg.roughness, rtol=1e-4) or not np.allclose(eta, cfg.ior, rtol=1e-4)):
                raise InputError(f"{what}: expected the object's rough dielectric BSDF (roughdielectric, ggx, alpha "
                                 f"{cfg.roughness}, int_ior {cfg.ior}, ext_ior 1), got {str(shape.bsdf()).split('[')[0]}"
                                 f" (alpha {alpha}, eta {eta}); `translucent_shape` builds the shape")
            if shape.interior_medium() is None:
                raise InputError(f"{what}: expected a black interior medium (homogeneous, albedo 0, sigma_t 1e6) so "
                                 "that the inner integrator renders the surface reflection alone; `translucent_shape` "
                                 "builds the shape")

        def _object_box(self) -> tuple[np.ndarray, np.ndarray]:
            if self.config.shape == "sphere":
                return -np.ones(3), np.ones(3)
            v = self._vertices()
            return v.min(0), v.max(0)

        def _vertices(self) -> np.ndarray:
            if self._object_vertices is None:
                mesh = mi.load_dict({"type": "ply", "filename": str(self.config.shape)})
                self._object_vertices = np.array(mi.traverse(mesh)["vertex_positions"],
                                                 dtype=np.float64).reshape(-1, 3)
            return self._object_vertices

        def _mesh_transform(self, world: np.ndarray, what: str) -> np.ndarray:
            """The 4 x 4 affine map of the object's vertices onto `world` (least squares), checked."""
            local = self._vertices()
            if local.shape != world.shape:
                raise InputError(f"{what}: {world.shape[0]} vertices, but the observations' object "
                                 f"{self.config.shape!r} has {local.shape[0]}: not the same mesh")
            homogeneous = np.concatenate([local, np.ones((local.shape[0], 1))], 1)
            a, *_ = np.linalg.lstsq(homogeneous, world, rcond=None)
            residual = float(np.abs(homogeneous @ a - world).max())
            size = float(np.linalg.norm(world.max(0) - world.min(0)))
            if not residual <= PLACEMENT_TOLERANCE * size:
                raise InputError(f"{what}: its vertices are not an affine image of the observations' mesh "
                                 f"{self.config.shape!r} (largest residual {residual:.3g}): not the same mesh")
            matrix = np.eye(4)
            matrix[:3, :] = a.T
            return matrix

        # ---- the subsurface estimate --------------------------------------------------------------------
        def _subsurface(self, scene, shape, sampler, n, rows, x_o, n_o, wo_o, r, centre):
            """(M, 3) float32 subsurface radiance at the M hit rows (one sample per strategy)."""
            u_light = sampler.next_2d()
            u_model = sampler.next_2d()
            out = torch.zeros(rows.numel(), 3, dtype=_DTYPE)
            model, dev = self.model, self._device()
            it = dr.zeros(mi.Interaction3f, rows.numel())
            it.p = mi.Point3f(*(mi.Float(float(c)) for c in centre))
            lobe = None  # the model's sampling lobe at every row, its network run once for sampling and densities
            if self.strategy in ("mis", "model") and hasattr(model, "incident_lobe"):
                with torch.no_grad():
                    lobe = model.incident_lobe(Query(wi=n_o.float(), wo=wo_o.float(), x=x_o.float(),
                                                     n=n_o.float()).to(dev))
            if self.strategy in ("mis", "light"):
                u = bsdf_plugin._vec(u_light, n)[rows]
                ds, weight = scene.sample_emitter_direction(it, mi.Point2f(*_columns(mi, u)), False, True)
                wi_w = bsdf_plugin._vec(ds.d, rows.numel()).double()
                visible = self._unoccluded(scene, shape, it, ds.d, ds.dist)
                weight = bsdf_plugin._vec(weight, rows.numel()) * visible[:, None]
                wi_o = _unit(wi_w @ r)
                f = _eval(model, dev, wi_o, x_o, wo_o)
                delta = _scalars(mi.has_flag(ds.emitter.flags(), mi.EmitterFlags.Delta), rows.numel()).bool()
                if self.strategy == "mis":
                    p_light = _scalars(ds.pdf, rows.numel()).float()
                    if lobe is not None:
                        with torch.no_grad():
                            p_model = lobe.pdf(wi_o.to(dev, torch.float32)).to("cpu", _DTYPE)
                    else:
                        p_model = _pdf(model, dev, wi_o, x_o, wo_o, n_o)
                    mis = torch.where(delta, torch.ones_like(p_light), p_light / (p_light + p_model).clamp(min=1e-30))
                    weight = weight * mis[:, None]
                out += torch.where(torch.isfinite(f * weight), f * weight, torch.zeros_like(f))
            if self.strategy in ("mis", "model"):
                u = bsdf_plugin._vec(u_model, n)[rows]
                with torch.no_grad():
                    if lobe is not None:
                        drawn = lobe.sample(u.to(dev, torch.float32))
                    else:
                        q = Query(wi=n_o.float(), wo=wo_o.float(), x=x_o.float(), n=n_o.float()).to(dev)
                        drawn = model.sample_incident(q, u.to(dev))
                    wi_o, p_model = (v.to("cpu", torch.float64) for v in drawn)
                wi_w = _unit(wi_o @ r.T)
                radiance, p_light = self._incident(scene, shape, it, wi_w)
                f = _eval(model, dev, wi_o, x_o, wo_o)
                mis = p_model / (p_model + p_light) if self.strategy == "mis" else torch.ones_like(p_model)
                weight = radiance * (mis / p_model.clamp(min=1e-30))[:, None]
                value = torch.where((p_model > 0)[:, None], f * weight.float(), torch.zeros_like(f))
                out += torch.where(torch.isfinite(value), value, torch.zeros_like(value))
            return out

        def _device(self):
            return next(self.model.parameters()).device

        def _trace_past_self(self, scene, shape, it, d, tmax=None):
            """The first surface interaction along rays from the centre `it` (Interaction3f) in directions d
            (Vector3f) up to tmax that is not on `shape`, tracing through the object's own surface up to
            SELF_PASSES times (invalid where nothing else is hit)."""
            m = dr.width(d)
            target = mi.ShapePtr(shape)
            origin = dr.zeros(mi.Point3f, m) + it.p
            maxt = dr.zeros(mi.Float, m) + (dr.largest(mi.Float) if tmax is None else tmax)
            pending = dr.full(mi.Bool, True, m)
            result = dr.zeros(mi.SurfaceInteraction3f, m)
            for _ in range(SELF_PASSES):
                ray = mi.Ray3f(origin, d)
                ray.maxt = maxt
                si = scene.ray_intersect(ray, pending)
                again = pending & si.is_valid() & (si.shape == target)
                result = dr.select(pending & ~again, si, result)
                if not bool(dr.any(again)):
                    return result
                pending = again
                origin = dr.select(again, si.spawn_ray(d).o, origin)
                maxt = dr.select(again, maxt - si.t, maxt)
            raise InputError(f"{PLUGIN_NAME}: rays from the centre of shape {self.shape_id!r} crossed its surface "
                             f"more than {SELF_PASSES} times")

        def _unoccluded(self, scene, shape, it, d, dist):
            """(M,) float32 1 where the emitter sample at `dist` along d from the centre is not blocked by
            another shape."""
            tmax = dr.select(dr.isfinite(dist), dist * (1 - 1e-4), dr.largest(mi.Float))
            si = self._trace_past_self(scene, shape, it, d, tmax)
            return 1.0 - _scalars(si.is_valid(), dr.width(dist)).float()

        def _incident(self, scene, shape, it, wi_w):
            """Radiance (M, 3) float64 arriving at the centre from directions wi_w (M, 3), and the density (M,)
            with which emitter sampling picks them."""
            d = mi.Vector3f(*_columns(mi, wi_w))
            si = self._trace_past_self(scene, shape, it, d)
            emitter = si.emitter(scene)
            m = wi_w.shape[0]
            radiance = bsdf_plugin._vec(emitter.eval(si, emitter != None), m).double()
            ds = mi.DirectionSample3f(scene, si, it)
            pdf = _scalars(scene.pdf_emitter_direction(it, ds, emitter != None), m)
            return radiance, pdf

    return NeumatTranslucentIntegrator


def _open_model(model):
    from ..catalog.modelfile import load_model
    from neumat.methods.neupress.model import NeuPreSS
    m = load_model(model) if isinstance(model, (str, Path)) else model
    if not hasattr(m, "sample_incident") or not getattr(m, "full_sphere", False) or not hasattr(m, "box_min"):
        raise InputError(f"{PLUGIN_NAME}: model: expected a NeuPreSS model (a full-sphere S_hat with "
                         f"sample_incident), got {type(m).__name__}")
    if not isinstance(m, NeuPreSS) and not hasattr(m, "incident_pdf"):
        raise InputError(f"{PLUGIN_NAME}: model {type(m).__name__} has no incident_pdf")
    return m


def _unit(v: torch.Tensor) -> torch.Tensor:
    return v / v.norm(dim=-1, keepdim=True).clamp(min=1e-30)


def _scalars(v, n: int) -> torch.Tensor:
    """A Dr.Jit scalar array (n lanes, or one broadcast value) as an (n,) float64 torch tensor."""
    a = torch.from_numpy(np.array(v, dtype=np.float64).reshape(-1))
    return a.expand(n).clone() if a.numel() == 1 else a


def _columns(mi, t: torch.Tensor):
    return tuple(mi.Float(t[:, i].float().contiguous()) for i in range(t.shape[1]))


def _eval(model, dev, wi, x, wo) -> torch.Tensor:
    """S_hat (M, 3) float32 on the CPU, in chunks."""
    with torch.no_grad():
        parts = [model.eval(Query(wi=wi[s].float(), wo=wo[s].float(), x=x[s].float()).to(dev)).to("cpu", _DTYPE)
                 for s in bsdf_plugin._chunks(wi.shape[0])]
    return torch.cat(parts) if parts else torch.zeros(0, 3, dtype=_DTYPE)


def _pdf(model, dev, wi, x, wo, n) -> torch.Tensor:
    with torch.no_grad():
        parts = [model.incident_pdf(Query(wi=wi[s].float(), wo=wo[s].float(), x=x[s].float(), n=n[s].float())
                                    .to(dev)).to("cpu", _DTYPE) for s in bsdf_plugin._chunks(wi.shape[0])]
    return torch.cat(parts) if parts else torch.zeros(0, dtype=_DTYPE)
