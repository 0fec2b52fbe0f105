"""The native Mitsuba 3 BSDF: a learned model evaluated by its Dr.Jit runtime (`neumat.export.drjit.runtime`) inside
Mitsuba's own kernels, symbolic (megakernel) mode included, without torch.

    from neumat.integrations import mitsuba_native
    mi = mitsuba_native.register()      # the "neumat" plugin; llvm_ad_rgb unless an RGB variant is already set
    bsdf = {"type": "neumat", "filename": "model.nmat"}   # or the folder `neumat export --format drjit` wrote

A set of materials (shared-neubrdf) renders its selected material (0 unless the model file says otherwise), or the
one named by the integer property `member`.

The plugin picks the native path whenever one exists (a drjit export, or a `.nmat` whose method declares a Dr.Jit
translator) and the torch bridge (`neumat.integrations.mitsuba`) otherwise; `"native": False` forces the bridge.
Conventions, sampling and footprints: docs/formats/drjit.md.
"""
from __future__ import annotations

import functools
import sys
import threading
from pathlib import Path

from ..core.errors import InputError

#: the plugin name registered with Mitsuba (the bridge's: one plugin, two paths)
PLUGIN_NAME = "neumat"


def register(variant: str | None = None):
    """Register the "neumat" BSDF plugin (native where possible, the torch bridge otherwise) and return the
    `mitsuba` module. variant: a Mitsuba RGB variant to set first (default: keep the current one, or set
    llvm_ad_rgb when none is set)."""
    mi = current_mitsuba() if variant is None else set_variant(variant)
    check_rgb(mi.variant())
    from ..export import drjit  # noqa: F401  (every runtime program, imported here, before Mitsuba's loader threads)
    mi.register_bsdf(PLUGIN_NAME, lambda props: make_bsdf(mi, props))
    return mi


#: held while the plugin factory builds a BSDF: Mitsuba instantiates a scene's plugins on several threads, and the
#: factory's first imports (the runtime's program modules, torch's side for a `.nmat`) from two threads at once can
#: leave one thread with a package only partly initialised (a CI run under load: "unknown program
#: 'healpix-grid-mlp'", the programs the package registers after the first two missing)
_BUILDING = threading.RLock()


def make_bsdf(mi, props):
    """The plugin factory: a native BSDF for a drjit export or a `.nmat` with a Dr.Jit translator (unless the
    property `native` is false), the torch bridge's BSDF otherwise. One at a time (`_BUILDING`)."""
    with _BUILDING:
        return _make_bsdf(mi, props)


def _make_bsdf(mi, props):
    source = None
    for key in ("filename", "material"):
        if key in props:
            source = props[key]
            break
    native = bool(props["native"]) if "native" in props else True
    if native and source is not None:
        runtime = native_runtime(source, mi.Float, mlp_form=props["mlp_form"] if "mlp_form" in props else None)
        if runtime is not None:
            if getattr(runtime, "translucent", False):
                raise InputError(f"neumat BSDF: {source!r} is a NeuPreSS object (S_hat of a whole translucent object), "
                                 "not a surface BSDF: render it with the integrator 'neumat_translucent' "
                                 "(neumat.integrations.mitsuba_translucent)")
            if "member" in props:  # a set of materials (shared-neubrdf): which one this BSDF renders
                if getattr(runtime, "materials", 1) < 2 or not callable(getattr(runtime, "select", None)):
                    raise InputError(f"neumat BSDF: 'member' given, but {source!r} holds one material")
                runtime.select(int(props["member"]))
            return native_class(mi.variant())(props, runtime)
    if _BRIDGE is None:
        raise InputError(f"neumat BSDF: {source!r} has no native (Dr.Jit) form or native is false; the torch bridge "
                         "renders it: register the plugin with neumat.integrations.mitsuba.register()")
    return _BRIDGE(mi)(props)


#: the torch bridge's class factory (mi -> BSDF class), set by `neumat.integrations.mitsuba` when it is imported, so
#: that this module never imports torch
_BRIDGE = None


def set_bridge(factory) -> None:
    """Install the torch bridge (`neumat.integrations.mitsuba` does, on import) as the fallback of `make_bsdf`."""
    global _BRIDGE
    _BRIDGE = factory


def native_runtime(source, backend, compute: str | None = None, mlp_form: str | None = None):
    """The Dr.Jit runtime of `source` (a drjit export folder or manifest, or a `.nmat` path whose model has a Dr.Jit
    translator; the latter is translated with torch), or None when it has none. compute, mlp_form: see
    `neumat.export.drjit.runtime.load_runtime`."""
    from ..export.drjit.runtime import is_export, load_runtime

    if not isinstance(source, (str, Path)):
        return None
    path = Path(source)
    if is_export(path):
        return load_runtime(path, backend, compute, mlp_form)
    if path.suffix != ".nmat" or not path.is_file():
        return None
    from ..export.drjit.format import drjit_models, export_drjit  # torch from here on
    from ..io.modelfile import read_header

    if read_header(path)["type"] not in drjit_models():
        return None
    from ..catalog.modelfile import load_model

    model = load_model(path, device="cpu")
    try:
        exported = export_drjit(model)
    except InputError:  # a configuration the translator does not cover: the bridge renders it
        return None
    runtime = load_runtime(exported.source(), backend, compute, mlp_form)
    if getattr(model, "can_sample", False) and not runtime.can_sample:
        return None  # a model whose learned sampler has no Dr.Jit form: the bridge keeps it (an export folder
        # of such a model still loads natively, sampled cosine-weighted)
    return runtime


def bsdf(source, variant: str | None = None, compute: str | None = None):
    """A native Mitsuba BSDF object for `source` (a drjit export, a `.nmat` with a Dr.Jit translator, or a
    `DrJitExport`), for use as a "bsdf" value in `mi.load_dict`; InputError when it has no native form."""
    mi = register(variant)
    if hasattr(source, "manifest") and hasattr(source, "arrays"):
        from ..export.drjit.runtime import load_runtime
        runtime = load_runtime((source.manifest, source.arrays), mi.Float, compute)
    else:
        runtime = native_runtime(source, mi.Float, compute)
    if runtime is None:
        raise InputError(f"{source!r}: no native (Dr.Jit) form; models with one: a drjit export, or a .nmat of "
                         "a model whose method declares a Dr.Jit translator (neumat list: exports 'drjit')")
    return native_class(mi.variant())(mi.Properties(PLUGIN_NAME), runtime)


def is_native(bsdf_object) -> bool:
    """Whether a Mitsuba BSDF object is this module's native BSDF."""
    return getattr(bsdf_object, "neumat_native", False) is True


# ------------------------------------------------------------------------------------------ variants

def set_variant(variant: str):
    from ..core.llvm import VARIANT
    from ..core.mitsuba import import_mitsuba

    if not isinstance(variant, str):
        raise InputError(f"variant: expected the name of a Mitsuba RGB variant, got {variant!r}")
    mi = import_mitsuba(variant if variant.startswith("cuda_") else VARIANT)
    if variant not in mi.variants():
        raise InputError(f"variant: expected one of the installed Mitsuba variants {mi.variants()}, got {variant!r}")
    check_rgb(variant)
    if mi.variant() != variant:
        mi.set_variant(variant)
    return mi


def check_rgb(variant: str) -> None:
    parts = variant.split("_")
    if "rgb" not in parts or "polarized" in parts:
        raise InputError(f"Mitsuba variant {variant!r}: the neumat plugin needs an unpolarised RGB variant "
                         "(for example llvm_ad_rgb or cuda_ad_rgb)")


def current_mitsuba():
    """The `mitsuba` module with its current variant, or with llvm_ad_rgb set when none is (imported by
    `import_mitsuba`, which chooses the LLVM first, when nobody has imported it yet). An LLVM variant set by the
    caller is checked against the chosen LLVM too (`configure_llvm`)."""
    from ..core.llvm import configure_llvm
    from ..core.mitsuba import import_mitsuba

    mi = sys.modules.get("mitsuba")
    if mi is None or mi.variant() is None:
        return import_mitsuba()
    if mi.variant().startswith("llvm_"):
        configure_llvm()
    return mi


# ------------------------------------------------------------------------------------------ the BSDF

@functools.cache
def native_class(variant: str) -> type:
    """The native BSDF class for Mitsuba variant `variant` (built once per variant)."""
    import drjit as dr
    import mitsuba as mi

    if mi.variant() != variant:
        raise InputError(f"native BSDF class for {variant!r} requested while Mitsuba's variant is {mi.variant()!r}")

    class NeumatNativeBSDF(mi.BSDF):
        """A neumat model on its Dr.Jit runtime as a one-sided glossy-reflection Mitsuba BSDF (module docstring)."""

        neumat_native = True

        def __init__(self, props, runtime):
            mi.BSDF.__init__(self, props)
            self.runtime = runtime
            flags = mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.FrontSide
            if runtime.spatially_varying:
                flags = flags | mi.BSDFFlags.SpatiallyVarying
            self.m_flags = flags
            self.m_components = [flags]

        def _where(self, si):
            """The uv and footprint arguments of the runtime: si.uv and the covariance in uv^2 of the box pixel
            filter over Mitsuba's uv partials, (J J^T) / 12 with J = [duv_dx, duv_dy] (zero without ray
            differentials: the finest level), for spatially varying models; None otherwise."""
            if not self.runtime.spatially_varying:
                return {}
            dx, dy = si.duv_dx, si.duv_dy
            cov = ((dx[0] * dx[0] + dy[0] * dy[0]) / 12, (dx[0] * dx[1] + dy[0] * dy[1]) / 12,
                   (dx[1] * dx[1] + dy[1] * dy[1]) / 12)
            return {"uv": (si.uv[0], si.uv[1]), "footprint": cov}

        def _mask(self, ctx, si, wo, active):
            """The active lanes with both directions above the surface (none when the context excludes the lobe)."""
            active = mi.Bool(active) & (mi.Frame3f.cos_theta(si.wi) > 0) & (mi.Frame3f.cos_theta(wo) > 0)
            if not ctx.is_enabled(mi.BSDFFlags.GlossyReflection, 0):
                active = active & False
            return active

        def _value(self, ctx, si, wo, active):
            """f(wi, wo) cos(theta_wo) on the active lanes with both directions above the surface, and that mask."""
            active = self._mask(ctx, si, wo, active)
            importance = ctx.mode == mi.TransportMode.Importance
            first, second = (wo, si.wi) if importance else (si.wi, wo)
            f = mi.Color3f(self.runtime.eval(mi.Vector3f(first), mi.Vector3f(second), active, **self._where(si)))
            return dr.select(active, f * mi.Frame3f.cos_theta(wo), 0.0), active

        def _pdf(self, si, wo, active):
            ok = active & (mi.Frame3f.cos_theta(si.wi) > 0)
            if self.runtime.can_sample:
                return dr.select(ok, mi.Float(self.runtime.pdf(mi.Vector3f(si.wi), mi.Vector3f(wo), ok,
                                                               **self._where(si))), 0.0)
            return dr.select(ok, mi.warp.square_to_cosine_hemisphere_pdf(wo), 0.0)

        def eval(self, ctx, si, wo, active=True):
            return self._value(ctx, si, wo, active)[0]

        def pdf(self, ctx, si, wo, active=True):
            ok = mi.Bool(active) & (mi.Frame3f.cos_theta(wo) > 0)
            if not ctx.is_enabled(mi.BSDFFlags.GlossyReflection, 0):
                ok = ok & False
            return self._pdf(si, wo, ok)

        def eval_pdf(self, ctx, si, wo, active=True):
            if self.runtime.can_sample and hasattr(self.runtime, "eval_pdf"):  # one latent read, one set of lobes
                ok = self._mask(ctx, si, wo, active)
                f, pdf = self.runtime.eval_pdf(mi.Vector3f(si.wi), mi.Vector3f(wo), ok, **self._where(si),
                                               swap=ctx.mode == mi.TransportMode.Importance)
                return (dr.select(ok, mi.Color3f(f) * mi.Frame3f.cos_theta(wo), 0.0),
                        dr.select(ok, mi.Float(pdf), 0.0))
            value, ok = self._value(ctx, si, wo, active)
            return value, self._pdf(si, wo, ok)

        def sample(self, ctx, si, sample1, sample2, active=True):
            shared = hasattr(self.runtime, "sample_eval")
            if self.runtime.can_sample:  # the model's own sampler on sample2, as the bridge's material.sample
                up = mi.Bool(active) & (mi.Frame3f.cos_theta(si.wi) > 0)
                if shared:  # one latent read and one set of lobes for direction, density and value
                    wo, pdf, f = self.runtime.sample_eval(mi.Vector3f(si.wi), sample2[0], sample2[1], up,
                                                          swap=ctx.mode == mi.TransportMode.Importance,
                                                          **self._where(si))
                else:
                    wo, pdf = self.runtime.sample(mi.Vector3f(si.wi), sample2[0], sample2[1], up, **self._where(si))
                wo, pdf = mi.Vector3f(wo), mi.Float(pdf)
            else:
                wo = mi.warp.square_to_cosine_hemisphere(sample2)
            if self.runtime.can_sample and shared:
                ok = self._mask(ctx, si, wo, active)
                value = dr.select(ok, mi.Color3f(f) * mi.Frame3f.cos_theta(wo), 0.0)
            else:
                value, ok = self._value(ctx, si, wo, active)
            if not self.runtime.can_sample:
                pdf = dr.select(ok, mi.warp.square_to_cosine_hemisphere_pdf(wo), 0.0)
            pdf = dr.select(ok, pdf, 0.0)
            bs = dr.zeros(mi.BSDFSample3f)
            bs.wo = wo
            bs.pdf = pdf
            bs.eta = 1.0
            bs.sampled_type = mi.UInt32(+mi.BSDFFlags.GlossyReflection)
            bs.sampled_component = mi.UInt32(0)
            ok = ok & (pdf > 0)
            return bs, dr.select(ok, value / dr.select(ok, pdf, 1.0), 0.0)

        def traverse(self, callback):
            """The runtime's latent pyramid (every level's texels, one flat Float; `Pyramid.data`) as the
            differentiable parameter "latent", where the runtime has one (Mitsuba's `mi.traverse`, `prb`)."""
            data = getattr(getattr(self.runtime, "pyramid", None), "data", None)
            if data is not None:
                callback.put("latent", data, mi.ParamFlags.Differentiable)

        def parameters_changed(self, keys):
            pass  # the kernels read the (updated in place) latent buffer as it is

        def to_string(self):
            return f"NeumatNativeBSDF[runtime={self.runtime.describe()!r}]"

    return NeumatNativeBSDF
