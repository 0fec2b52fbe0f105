"""Mitsuba 3 integrator plugin that puts a NeuPreSS translucent object (a model of
`neumat fit OBS.npz --model neupress`) in a Mitsuba scene with other objects and lights.

`register()` adds the integrator "neumat_translucent", `translucent_shape(observations, to_world=T)` places
the object, `render(scene, spp)` renders (evaluated mode). The inner integrator renders the object's rough
dielectric surface; the plugin adds the learned subsurface term under distant light (TG et al., Eq. 5).

A NeuPreSS (.nmat, object, or drjit export folder) runs on its Dr.Jit runtime (program "neupress"), no torch while
rendering; `"native": false` or another kind of model keeps the torch path (docs/mitsuba.md).

Details: docs/formats/mitsuba_plugins.md, section `neumat.integrations.mitsuba_translucent`.
"""
from __future__ import annotations

import functools
from pathlib import Path

import numpy as np

from ..core.errors import InputError
from . import mitsuba_native

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


def register(variant: str | None = None):
    """Register the "neumat_translucent" integrator (and the "neumat" BSDF) and return the `mitsuba` module;
    variant as in `neumat.integrations.mitsuba.register`."""
    mi = mitsuba_native.register(variant)
    if mitsuba_native._BRIDGE is None:  # the "neumat" BSDF's torch fallback, imported only when a BSDF needs it
        mitsuba_native.set_bridge(_lazy_bridge)
    cls = _integrator_class(mi)
    mi.register_integrator(PLUGIN_NAME, lambda props: cls(props))
    return mi


def _lazy_bridge(mi):
    from . import mitsuba as bsdf_plugin  # torch from here on; it installs itself as the bridge
    return bsdf_plugin._bsdf_class(mi)


def render(scene, spp: int | None = None, seed: int = 0, sensor: int = 0):
    """`neumat.integrations.mitsuba.render`: the scene in evaluated mode, (H, W, C) float32 linear RGB torch tensor
    (imports torch; a native model renders with plain `mi.render` too)."""
    from . import mitsuba as bsdf_plugin
    return bsdf_plugin.render(scene, spp=spp, seed=seed, sensor=sensor)


class ObjectFields:
    """The three fields of an object's `TranslucentConfig` the integrator reads (shape, roughness, ior)."""

    def __init__(self, shape: str = "sphere", roughness: float = 0.3, ior: float = 1.5) -> None:
        self.shape, self.roughness, self.ior = shape, roughness, ior


def object_fields(source):
    """The object's shape, roughness and ior from an observations file without torch (numpy and json; the file's
    other fields are not checked, which `object_config` does), from a dict of config fields, or from a config."""
    import json
    import zipfile

    if isinstance(source, (str, Path)):
        path = Path(source)
        try:
            with np.load(path) as data:
                saved = json.loads(str(data["source"])) if "source" in data.files else None
        except (ValueError, OSError, EOFError, zipfile.BadZipFile) as e:
            raise InputError(f"observations {str(source)!r}: not a neumat observations file ({e})") from None
        if not isinstance(saved, dict) or not isinstance(saved.get("object"), dict):
            raise InputError(f"observations {str(source)!r}: no object description (write it with "
                             "`neumat translucent trace`)")
        source = saved["object"]
    if isinstance(source, dict):
        f = ObjectFields()
        shape, roughness, ior = (source.get(k, getattr(f, k)) for k in ("shape", "roughness", "ior"))
        if not isinstance(shape, str) or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and v > 0
                                                 for v in (roughness, ior)):
            raise InputError(f"translucent object: expected a shape name and positive roughness and ior, got "
                             f"{shape!r}, {roughness!r}, {ior!r}")
        return ObjectFields(shape, float(roughness), float(ior))
    return source


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
    unit sphere, "cube": Mitsuba's [-1, 1]^3, or the PLY mesh) with the rough dielectric of its config (GGX alpha,
    ior) and a black interior, placed by `to_world` (a `mi.ScalarTransform4f`, a 4 x 4 matrix, or None), with id
    `shape_id` (what the integrator's "shape" names)."""
    from ..reflectance.translucent import outer_shape_dict

    cfg = object_config(source)
    mi = mitsuba_native.current_mitsuba()
    shape = outer_shape_dict(cfg)
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
            native = bool(props["native"]) if "native" in props else True
            self.model, self.runtime = _open_model(props["model"] if model is None else model, native, mi.Float)
            observations = props["observations"] if source is None else source
            # without torch when the model loaded without it (a drjit export): the three fields it reads
            self.config = object_fields(observations) if self.model is None else object_config(observations)
            self._object_vertices = None

        def aov_names(self):
            return self.inner.aov_names()

        def to_string(self):
            return (f"NeumatTranslucent[shape={self.shape_id!r}, strategy={self.strategy!r}, "
                    f"{'native' if self.runtime is not None else 'torch'}, inner={self.inner}]")

        @property
        def native(self) -> bool:
            """Whether the model runs on its Dr.Jit runtime (no torch while rendering)."""
            return self.runtime is not None

        def sample(self, scene, sampler, ray, medium=None, active=True):
            result = self.inner.sample(scene, sampler, ray, medium, active)
            if self.runtime is not None:
                return self._sample_native(scene, sampler, ray, active, result)
            import torch

            from . import mitsuba as bsdf_plugin
            if bsdf_plugin._symbolic(dr):
                return result
            L, valid, aovs = result
            shape, place = self._placement(scene)
            place = tuple(torch.from_numpy(np.asarray(v, dtype=np.float64)) for v in place)
            _DTYPE = torch.float32
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

        def _sample_native(self, scene, sampler, ray, active, result):
            """`sample` on the Dr.Jit runtime: the same estimators as `_subsurface` over the whole wavefront (lanes
            off the object masked), in fp32 Dr.Jit arrays."""
            L, valid, aovs = result
            shape, (r, s, t, centre) = self._placement(scene)
            si = scene.ray_intersect(mi.Ray3f(ray), active)
            on = si.is_valid() & (si.shape == mi.ShapePtr(shape)) & active
            inv_s = 1.0 / float(s)
            x_o = _rotate_t(mi, r, si.p - mi.Vector3f(*(float(v) for v in t))) * inv_s
            n_o, wo_o = dr.normalize(_rotate_t(mi, r, si.n)), dr.normalize(_rotate_t(mi, r, -ray.d))
            total = mi.Color3f(0.0)
            for _ in range(self.samples):
                total += self._subsurface_native(scene, shape, sampler, on, x_o, n_o, wo_o, r, centre)
            total = dr.select(on, total / self.samples, 0.0)
            return L + total, valid, aovs

        def _subsurface_native(self, scene, shape, sampler, on, x_o, n_o, wo_o, r, centre):
            rt = self.runtime
            u_light = sampler.next_2d()
            u_model = sampler.next_2d()
            n = dr.width(on)
            it = dr.zeros(mi.Interaction3f, n)
            it.p = mi.Point3f(*(float(c) for c in centre))
            out = mi.Color3f(0.0)
            lobe = rt.lobe(x_o, wo_o, n_o) if self.strategy in ("mis", "model") else None
            if self.strategy in ("mis", "light"):
                ds, weight = scene.sample_emitter_direction(it, u_light, False, on)
                visible = self._unoccluded_mask(scene, shape, it, ds.d, ds.dist, on)
                wi_o = dr.normalize(_rotate_t(mi, r, ds.d))
                f = rt.eval(wi_o, wo_o, on, x=x_o)
                w = dr.select(visible, weight, 0.0)
                if self.strategy == "mis":
                    delta = mi.has_flag(ds.emitter.flags(), mi.EmitterFlags.Delta)
                    p_model = lobe.pdf([wi_o.x, wi_o.y, wi_o.z])
                    w = w * dr.select(delta, 1.0, ds.pdf / dr.maximum(ds.pdf + p_model, 1e-30))
                out += _finite(dr, f * w)
            if self.strategy in ("mis", "model"):
                wi, p_model = lobe.sample(u_model.x, u_model.y)
                wi_o = mi.Vector3f(*wi)
                wi_w = dr.normalize(_rotate(mi, r, wi_o))
                radiance, p_light = self._incident_native(scene, shape, it, wi_w, on)
                f = rt.eval(wi_o, wo_o, on, x=x_o)
                mis = p_model / (p_model + p_light) if self.strategy == "mis" else 1.0
                value = dr.select(on & (p_model > 0), f * radiance * (mis / dr.maximum(p_model, 1e-30)), 0.0)
                out += _finite(dr, value)
            return out

        def _unoccluded_mask(self, scene, shape, it, d, dist, active=True):
            """Where the emitter sample at `dist` along d from the centre is not blocked by another shape."""
            tmax = dr.select(dr.isfinite(dist), dist * (1 - 1e-4), dr.largest(mi.Float))
            si = self._trace_past_self(scene, shape, it, d, tmax, active)
            return ~si.is_valid()

        def _incident_native(self, scene, shape, it, wi_w, active):
            """Radiance (Color3f) arriving at the centre from wi_w, and the emitter-sampling density (Float)."""
            si = self._trace_past_self(scene, shape, it, wi_w, None, active)
            emitter = si.emitter(scene)
            hit = active & (emitter != None)  # noqa: E711  (Dr.Jit's pointer comparison)
            radiance = emitter.eval(si, hit)
            pdf = scene.pdf_emitter_direction(it, mi.DirectionSample3f(scene, si, it), hit)
            return dr.select(hit, radiance, 0.0), dr.select(hit, pdf, 0.0)

        # ---- placement ----------------------------------------------------------------------------------
        def _placement(self, scene):
            """(the shape, (R (3, 3), s, t (3,), centre (3,) world, all float64 numpy))."""
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
            if self.runtime is not None:
                model_lo, model_hi = (np.asarray(v, np.float64) for v in (self.runtime.box_min, self.runtime.box_max))
            else:
                model_lo = self.model.box_min.detach().double().cpu().numpy()
                model_hi = self.model.box_max.detach().double().cpu().numpy()
            diagonal = float(np.linalg.norm(hi - lo))
            if max(np.abs(model_lo - lo).max(), np.abs(model_hi - hi).max()) > 1e-3 * diagonal:
                raise InputError(f"{PLUGIN_NAME}: the model's object-space box {np.round(model_lo, 4).tolist()} - "
                                 f"{np.round(model_hi, 4).tolist()} is not the box of the observations' object "
                                 f"{np.round(lo, 4).tolist()} - {np.round(hi, 4).tolist()}: the model was fitted to "
                                 "another object (or placed elsewhere)")
            centre = t + s * (r @ ((lo + hi) / 2))
            return shape, (r, s, t, centre)

        def _check_surface(self, shape, params, what):
            """The shape must carry the object's rough dielectric (the model excludes that reflection) and an
            interior medium (black, so that the inner integrator renders the reflection alone)."""
            cfg = self.config
            alpha = np.array(params["bsdf.alpha.value"]).ravel() if "bsdf.alpha.value" in params else None
            eta = np.array(params["bsdf.eta"]).ravel() if "bsdf.eta" in params else None
            if (not str(shape.bsdf()).startswith("RoughDielectric") or alpha is None or eta is None
                    or not np.allclose(alpha, cfg.roughness, rtol=1e-4) or not np.allclose(eta, cfg.ior, rtol=1e-4)):
                raise InputError(f"{what}: expected the object's rough dielectric BSDF (roughdielectric, ggx, alpha "
                                 f"{cfg.roughness}, int_ior {cfg.ior}, ext_ior 1), "
                                 f"got {str(shape.bsdf()).split('[')[0]}"
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
                from ..reflectance.translucent import outer_shape_dict

                mesh = mi.load_dict(outer_shape_dict(self.config))  # a PLY mesh, or Mitsuba's cube (a mesh too)
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
            import torch

            from ..core.query import Query
            from . import mitsuba as bsdf_plugin
            _DTYPE = torch.float32
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

        def _trace_past_self(self, scene, shape, it, d, tmax=None, active=True):
            """The first surface interaction along rays from the centre `it` (Interaction3f) in directions d
            (Vector3f) up to tmax that is not on `shape`, tracing through the object's own surface up to
            SELF_PASSES times (invalid where nothing else is hit or on inactive lanes)."""
            m = dr.width(d)
            target = mi.ShapePtr(shape)
            origin = dr.zeros(mi.Point3f, m) + it.p
            maxt = dr.zeros(mi.Float, m) + (dr.largest(mi.Float) if tmax is None else tmax)
            pending = dr.full(mi.Bool, True, m) & active
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
            return 1.0 - _scalars(si.is_valid(), dr.width(dist)).float()  # torch path

        def _incident(self, scene, shape, it, wi_w):
            """Radiance (M, 3) float64 arriving at the centre from directions wi_w (M, 3), and the density (M,)
            with which emitter sampling picks them."""
            from . import mitsuba as bsdf_plugin
            d = mi.Vector3f(*_columns(mi, wi_w))
            si = self._trace_past_self(scene, shape, it, d)
            emitter = si.emitter(scene)
            m = wi_w.shape[0]
            radiance = bsdf_plugin._vec(emitter.eval(si, emitter != None), m).double()
            ds = mi.DirectionSample3f(scene, si, it)
            pdf = _scalars(scene.pdf_emitter_direction(it, ds, emitter != None), m)
            return radiance, pdf

    return NeumatTranslucentIntegrator


def _open_model(model, native: bool = True, backend=None):
    """(torch model or None, Dr.Jit runtime or None) of `model`: a NeuPreSS `.nmat` path or object (native: its
    runtime, translated here with torch), a drjit export folder of one, a `DrJitExport` or a runtime (native only), or
    another full-sphere model with sample_incident and incident_pdf (torch)."""
    from ..export.drjit.runtime import Runtime, is_export, load_runtime

    backend = "llvm" if backend is None else backend
    if isinstance(model, Runtime) or (isinstance(model, (str, Path)) and is_export(model)) or \
            (hasattr(model, "manifest") and hasattr(model, "arrays")):
        if not native:
            raise InputError(f"{PLUGIN_NAME}: a Dr.Jit runtime or export has no torch path (native: false)")
        rt = model if isinstance(model, Runtime) else \
            load_runtime(model if isinstance(model, (str, Path)) else model.source(), backend)
        if not getattr(rt, "translucent", False):
            raise InputError(f"{PLUGIN_NAME}: model: expected a NeuPreSS (program 'neupress'), got program "
                             f"{rt.manifest.get('program')!r}")
        return None, rt
    m = _open_torch_model(model)
    if native:
        from ..export.drjit.format import export_drjit
        from neumat.methods.neupress.model import NeuPreSS
        if isinstance(m, NeuPreSS):
            try:
                return m, load_runtime(export_drjit(m, "fp32").source(), backend)
            except InputError:  # a configuration the translator does not cover: the torch path
                pass
    return m, None


def _rotate_t(mi, r, v):
    """R^T v for a numpy (3, 3) R and a Dr.Jit 3-vector v (world to object space, before the scale)."""
    return mi.Vector3f(*(float(r[0, i]) * v.x + float(r[1, i]) * v.y + float(r[2, i]) * v.z for i in range(3)))


def _rotate(mi, r, v):
    """R v (object to world space)."""
    return mi.Vector3f(*(float(r[i, 0]) * v.x + float(r[i, 1]) * v.y + float(r[i, 2]) * v.z for i in range(3)))


def _finite(dr, c):
    return dr.select(dr.isfinite(c), c, 0.0)


def _open_torch_model(model):
    from ..catalog.modelfile import load_model
    from neumat.methods.neupress.model import NeuPreSS
    m = load_model(model) if isinstance(model, (str, Path)) else model
    if not hasattr(m, "sample_incident") or not getattr(m, "full_sphere", False) or not hasattr(m, "box_min"):
        raise InputError(f"{PLUGIN_NAME}: model: expected a NeuPreSS model (a full-sphere S_hat with "
                         f"sample_incident), got {type(m).__name__}")
    if not isinstance(m, NeuPreSS) and not hasattr(m, "incident_pdf"):
        raise InputError(f"{PLUGIN_NAME}: model {type(m).__name__} has no incident_pdf")
    return m


def _unit(v):
    return v / v.norm(dim=-1, keepdim=True).clamp(min=1e-30)


def _scalars(v, n: int):
    """A Dr.Jit scalar array (n lanes, or one broadcast value) as an (n,) float64 torch tensor."""
    import torch
    a = torch.from_numpy(np.array(v, dtype=np.float64).reshape(-1))
    return a.expand(n).clone() if a.numel() == 1 else a


def _columns(mi, t):
    return tuple(mi.Float(t[:, i].float().contiguous()) for i in range(t.shape[1]))


def _eval(model, dev, wi, x, wo):
    """S_hat (M, 3) float32 on the CPU, in chunks."""
    import torch

    from ..core.query import Query
    from . import mitsuba as bsdf_plugin
    _DTYPE = torch.float32
    with torch.no_grad():
        parts = [model.eval(Query(wi=wi[s].float(), wo=wo[s].float(), x=x[s].float()).to(dev)).to("cpu", _DTYPE)
                 for s in bsdf_plugin._chunks(wi.shape[0])]
    return torch.cat(parts) if parts else torch.zeros(0, 3, dtype=_DTYPE)


def _pdf(model, dev, wi, x, wo, n):
    import torch

    from ..core.query import Query
    from . import mitsuba as bsdf_plugin
    _DTYPE = torch.float32
    with torch.no_grad():
        parts = [model.incident_pdf(Query(wi=wi[s].float(), wo=wo[s].float(), x=x[s].float(), n=n[s].float())
                                    .to(dev)).to("cpu", _DTYPE) for s in bsdf_plugin._chunks(wi.shape[0])]
    return torch.cat(parts) if parts else torch.zeros(0, dtype=_DTYPE)
