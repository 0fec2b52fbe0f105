"""Mitsuba 3 BSDF plugin for any neumat `Material`: path-trace a fitted model inside a Mitsuba scene.

    from neumat.integrations import mitsuba as nm_mitsuba
    mi = nm_mitsuba.register()          # the llvm_ad_rgb variant unless an RGB variant is already set
    scene = mi.load_dict({..., "shape": {"type": "ply", ..., "bsdf": {"type": "neumat", "material": "m.nmat"}}})
    image = nm_mitsuba.render(scene, spp=64)        # (H, W, 3) float32 torch tensor, linear RGB

`material` is anything `neumat.open_material` reads (a `.nmat` model, a MERL / RGL / BTF file, a texture-set
folder or an analytic spec such as "ggx:roughness=0.2"); `bsdf(material)` wraps a Material object instead.

Details: docs/formats/mitsuba_plugins.md, section `neumat.integrations.mitsuba`.
"""
from __future__ import annotations

import contextlib
import functools
import re
import sys
from pathlib import Path

import numpy as np
import torch

from ..core.errors import InputError, NeumatError
from ..core.material import Material, material_device
from ..core.query import Query
from ..warp.hemisphere import sample_cosine_hemisphere
from . import mitsuba_native
from .mitsuba_native import current_mitsuba as _current_mitsuba

#: the plugin name registered with Mitsuba
PLUGIN_NAME = "neumat"
#: rows per torch call (bounds the memory of large wavefronts through neural models)
CHUNK = 1 << 18
#: the precision of the torch side (Mitsuba's RGB variants are single precision)
_DTYPE = torch.float32


def register(variant: str | None = None):
    """Register the "neumat" BSDF plugin and return the `mitsuba` module. Its `material` (or `filename`) property
    takes a drjit export or a `.nmat` of a model with a Dr.Jit runtime natively (`neumat.integrations.mitsuba_native`:
    no torch while rendering, symbolic mode) unless `native` is false, anything else through this torch bridge.

    variant: a Mitsuba RGB variant to set first (default: keep the current one, or set llvm_ad_rgb when none
    is set). Registering again (or for another variant) is harmless."""
    return mitsuba_native.register(variant)  # one plugin: native where a Dr.Jit runtime exists, else this bridge


def bsdf(material: Material | str | Path):
    """A Mitsuba BSDF object around `material` (a Material, or anything `open_material` reads), for use as
    the value of a "bsdf" entry in `mi.load_dict`, for the current variant (see `register`)."""
    mi = register()
    return _bsdf_class(mi)(mi.Properties(PLUGIN_NAME), material=material)


@contextlib.contextmanager
def evaluated_mode():
    """Within the block, Dr.Jit evaluates loops, virtual calls and conditionals instead of recording them
    symbolically, as the plugin needs. The previous flags are restored on exit."""
    import drjit as dr
    flags = (dr.JitFlag.SymbolicLoops, dr.JitFlag.SymbolicCalls, dr.JitFlag.SymbolicConditionals)
    before = [dr.flag(f) for f in flags]
    try:
        for f in flags:
            dr.set_flag(f, False)
        yield
    finally:
        for f, b in zip(flags, before):
            dr.set_flag(f, b)


def render(scene, spp: int | None = None, seed: int = 0, sensor: int = 0) -> torch.Tensor:
    """`mi.render(scene, spp=spp, seed=seed, sensor=sensor)` as a float32 (H, W, C) torch tensor on the CPU (linear
    RGB, plus any extra film channels): in evaluated mode when the scene holds a torch-bridge BSDF or a neumat
    integrator (`needs_evaluated_mode`), in Mitsuba's default (symbolic) mode otherwise, e.g. when every neumat
    BSDF in it is native."""
    mi = _current_mitsuba()
    if not isinstance(scene, mi.Scene):
        raise InputError(f"scene: expected a mitsuba Scene (mi.load_dict / mi.load_file), got {type(scene).__name__}")
    check_renderable(scene, sensor)
    with evaluated_mode() if needs_evaluated_mode(scene) else contextlib.nullcontext():
        try:
            image = mi.render(scene, spp=0 if spp is None else spp, seed=seed, sensor=sensor)
        except RuntimeError as e:  # Dr.Jit wraps an error of the plugin in its own
            raise unwrap_error(e) or e from None
    return torch.from_numpy(np.array(image, dtype=np.float32))


def needs_evaluated_mode(scene) -> bool:
    """Whether `scene` holds something that hands arrays to torch (a torch-bridge neumat BSDF, possibly inside
    another BSDF such as twosided, or an integrator of neumat's), which Dr.Jit's symbolic mode cannot feed."""
    if type(scene.integrator()).__module__.startswith("neumat."):
        return True
    for shape in scene.shapes():
        bsdf = shape.bsdf()
        if bsdf is None:
            continue
        if type(bsdf).__module__.startswith("neumat.") and not mitsuba_native.is_native(bsdf):
            return True
        if "NeumatBSDF" in str(bsdf):  # a bridge BSDF nested in a Mitsuba BSDF (twosided, blendbsdf, ...)
            return True
    return False


def check_renderable(scene, sensor: int = 0) -> None:
    """InputError naming what keeps `mi.render` from rendering `scene` with sensor number `sensor`: no integrator,
    no such sensor, a film without pixels or with more values than a Dr.Jit array holds (2^32). Mitsuba would
    raise deep inside its render call instead."""
    if scene.integrator() is None:
        raise InputError('the scene has no integrator; add one, e.g. <integrator type="path"/>')
    sensors = scene.sensors()
    if not sensors:
        raise InputError('the scene has no sensor; add one, e.g. <sensor type="perspective"> with a film')
    if not 0 <= sensor < len(sensors):
        raise InputError(f"sensor: expected an index below the scene's {len(sensors)} sensors, got {sensor}")
    w, h = (int(v) for v in sensors[sensor].film().crop_size())
    if w < 1 or h < 1 or w * h * 4 >= 2 ** 32:  # an RGB film stores at least 4 values (+ weight) per pixel
        raise InputError(f"the scene's film is {w} x {h} pixels; expected width and height >= 1 and fewer than "
                         "2^32 / 4 pixels (2^32 values: the most a Dr.Jit array holds)")


def unwrap_error(error: BaseException) -> NeumatError | None:
    """The neumat error that Mitsuba or Dr.Jit wrapped in `error`: one in its cause chain (errors raised while
    rendering), or one quoted with its traceback in the message (errors raised while a scene loads, then
    prefixed by Mitsuba's location, e.g. 'At dictionary node "s.bsdf"'); None when there is none."""
    seen, chain = error, 0
    while seen is not None and chain < 32:
        if isinstance(seen, NeumatError):
            return seen
        seen, chain = seen.__cause__ or seen.__context__, chain + 1
    head, sep, tail = str(error).partition("Traceback (most recent call last):")
    quoted = re.search(r"^(\w+): (.*)\Z", tail, re.M | re.S) if sep else None
    if quoted is None or quoted.group(1) not in ("InputError", "DataFormatError", "UnknownNameError"):
        return None
    where = re.sub(r"^\[[\w.]+:\d+\]\s*", "", head).rstrip(": \n")
    return InputError(f"{where}: {quoted.group(2).strip()}" if where else quoted.group(2).strip())


def _bsdf_class(mi) -> type:
    """The plugin class for mi's current variant, built once per variant (Mitsuba's base classes differ per
    variant)."""
    return _bsdf_class_of(mi.variant())


@functools.cache
def _bsdf_class_of(variant: str) -> type:
    import mitsuba as mi

    return _make_bsdf_class(mi)


def _make_bsdf_class(mi) -> type:
    import drjit as dr

    class NeumatBSDF(mi.BSDF):
        """A neumat Material as a one-sided glossy-reflection Mitsuba BSDF (see the module docstring)."""

        def __init__(self, props, material=None):
            mi.BSDF.__init__(self, props)
            if material is None:
                key = next((k for k in ("material", "filename") if k in props), None)
                if key is None:
                    raise InputError("neumat BSDF: the 'material' property (a model file, measured file, "
                                     "texture-set folder or analytic spec) is required")
                material = props[key]
            self.material = _open(material)
            flags = mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.FrontSide
            if self.material.spatially_varying:
                flags = flags | mi.BSDFFlags.SpatiallyVarying
            self.m_flags = flags
            self.m_components = [flags]
            self._device = material_device(self.material)

        def eval(self, ctx, si, wo, active=True):
            value, _ = self._eval_pdf(ctx, si, wo, active, want_pdf=False)
            return value

        def pdf(self, ctx, si, wo, active=True):
            _, pdf = self._eval_pdf(ctx, si, wo, active, want_value=False)
            return pdf

        def eval_pdf(self, ctx, si, wo, active=True):
            return self._eval_pdf(ctx, si, wo, active)

        def sample(self, ctx, si, sample1, sample2, active=True):
            if _symbolic(dr):
                n = dr.width((si.wi, sample2))
                bs = dr.zeros(mi.BSDFSample3f, n)
                bs.wo = mi.Vector3f(0, 0, 1)
                return bs, _poison(mi, dr, active, n)
            n = dr.width((si.wi, sample2, active))
            bs = dr.zeros(mi.BSDFSample3f, n)
            viewer = _vec(si.wi, n)
            ok = _mask(active, n) & (viewer[:, 2] > 0) & _enabled(ctx, mi)
            rows = ok.nonzero().squeeze(1)
            wo = torch.zeros_like(viewer)
            wo[:, 2] = 1.0
            pdf = torch.zeros(viewer.shape[0], dtype=_DTYPE)
            weight = torch.zeros(viewer.shape[0], 3, dtype=_DTYPE)
            if rows.numel():
                u = _vec(sample2, n)[rows]
                uv = self._uv(si, rows, n)
                w_s, p_s = self._sample(viewer[rows], u, uv)
                good = (p_s > 0) & (w_s[:, 2] > 0) & torch.isfinite(w_s).all(-1) & torch.isfinite(p_s)
                w_s = torch.where(good[:, None], w_s, wo[rows])
                first, second = (w_s, viewer[rows]) if _importance(ctx, mi) else (viewer[rows], w_s)
                f = self._call(self.material.eval, first, second, uv)
                ratio = f * w_s[:, 2:3] / torch.where(good, p_s, torch.ones_like(p_s))[:, None]
                weight[rows] = torch.where(good[:, None] & torch.isfinite(ratio), ratio, torch.zeros_like(ratio))
                pdf[rows] = torch.where(good, p_s, torch.zeros_like(p_s))
                wo[rows] = w_s
            bs.wo = mi.Vector3f(*(mi.Float(wo[:, i].contiguous()) for i in range(3)))
            bs.pdf = mi.Float(pdf)
            bs.eta = 1.0
            bs.sampled_type = mi.UInt32(+mi.BSDFFlags.GlossyReflection)
            bs.sampled_component = mi.UInt32(0)
            return bs, _color(mi, weight)

        def to_string(self):
            return f"NeumatBSDF[material={self.material.describe()!r}]"

        # --- torch side ---------------------------------------------------------------------------

        def _eval_pdf(self, ctx, si, wo, active, want_value=True, want_pdf=True):
            if _symbolic(dr):
                n = dr.width((si.wi, wo))
                return _poison(mi, dr, active, n), dr.zeros(mi.Float, n)
            n = dr.width((si.wi, wo, active))
            viewer, other = _vec(si.wi, n), _vec(wo, n)
            ok = _mask(active, n) & (viewer[:, 2] > 0) & (other[:, 2] > 0) & _enabled(ctx, mi)
            rows = ok.nonzero().squeeze(1)
            value = torch.zeros(n, 3, dtype=_DTYPE)
            pdf = torch.zeros(n, dtype=_DTYPE)
            if rows.numel():
                uv = self._uv(si, rows, n)
                v, o = viewer[rows], other[rows]
                if want_value:
                    first, second = (o, v) if _importance(ctx, mi) else (v, o)
                    f = self._call(self.material.eval, first, second, uv)
                    value[rows] = f * o[:, 2:3]
                if want_pdf:
                    pdf[rows] = self._pdf(v, o, uv)
            return _color(mi, value), mi.Float(pdf)

        def _uv(self, si, rows, n):
            if not self.material.spatially_varying:
                return None
            return torch.remainder(_vec(si.uv, n)[rows], 1.0)

        def _sample(self, viewer, u, uv):
            """Directions wo (M, 3) drawn given si.wi (M, 3), and their densities (M,)."""
            if not self.material.can_sample:
                w = sample_cosine_hemisphere(u)
                return w, w[:, 2].clamp(min=0) / np.pi
            with torch.no_grad():
                out = [self.material.sample(_query(viewer[s], None, uv, s, self._device), u[s].to(self._device))
                       for s in _chunks(viewer.shape[0])]
            return (torch.cat([o.wo for o in out]).to("cpu", _DTYPE),
                    torch.cat([o.pdf for o in out]).to("cpu", _DTYPE))

        def _pdf(self, viewer, light, uv):
            if not self.material.can_sample:
                return light[:, 2].clamp(min=0) / np.pi
            return self._call(self.material.pdf, viewer, light, uv)

        def _call(self, fn, wi, wo, uv):
            with torch.no_grad():
                parts = [fn(_query(wi[s], wo[s], uv, s, self._device)) for s in _chunks(wi.shape[0])]
            out = torch.cat(parts).to("cpu", _DTYPE)
            if not bool(torch.isfinite(out).all()):
                raise InputError(f"neumat BSDF: material {self.material.describe()!r} returned non-finite "
                                 "values (NaN or inf)")
            return out

    return NeumatBSDF


def _open(material) -> Material:
    if isinstance(material, Material):
        if material.full_sphere:
            raise InputError(f"material {material.name!r}: full-sphere (translucent) materials are whole objects, "
                             "not surface BSDFs; the Mitsuba plugin takes reflectance materials")
        return material
    if isinstance(material, (str, Path)):
        from ..catalog.open_material import open_material
        return _open(open_material(material))
    raise InputError(f"material: expected a neumat Material, a file path or a spec string, "
                     f"got {type(material).__name__}")


def _symbolic(dr) -> bool:
    """Whether Dr.Jit is recording symbolically (then the inputs hold no values torch could read)."""
    return bool(dr.flag(dr.JitFlag.SymbolicScope))


def _poison(mi, dr, active, n: int):
    """Color3f of n lanes: NaN on the active lanes, 0 elsewhere. What a symbolic trace gets: Mitsuba traces
    every live BSDF, so for scenes without this BSDF no lane is active and the value is never used; a lane
    that does reach it in symbolic mode makes its pixel NaN instead of a plausible wrong value."""
    mask = dr.zeros(mi.Bool, n) | mi.Bool(active)
    nan = dr.select(mask, mi.Float(float("nan")), mi.Float(0.0))
    return mi.Color3f(nan, nan, nan)


def _vec(v, n: int) -> torch.Tensor:
    """A Dr.Jit vector or point (D components over n lanes, or one broadcast value) as a (n, D) torch tensor
    on the CPU."""
    t = torch.from_numpy(np.array(v, dtype=np.float32).reshape(len(v), -1).T.copy()).to(_DTYPE)
    return t.expand(n, -1) if t.shape[0] == 1 else t


def _mask(active, n: int) -> torch.Tensor:
    m = torch.from_numpy(np.array(active, dtype=bool)).reshape(-1)
    return m.expand(n) if m.numel() == 1 else m


def _enabled(ctx, mi) -> bool:
    return bool(ctx.is_enabled(mi.BSDFFlags.GlossyReflection, 0))


def _importance(ctx, mi) -> bool:
    return ctx.mode == mi.TransportMode.Importance


def _color(mi, rgb: torch.Tensor):
    return mi.Color3f(*(mi.Float(rgb[:, i].contiguous()) for i in range(3)))


def _chunks(n: int):
    return [slice(s, min(s + CHUNK, n)) for s in range(0, n, CHUNK)]


def _query(wi, wo, uv, rows: slice, device) -> Query:
    return Query(wi.to(device), None if wo is None else wo.to(device),
                 uv=None if uv is None else uv[rows].to(device))


mitsuba_native.set_bridge(_bsdf_class)  # the "neumat" plugin's fallback for sources without a native form
