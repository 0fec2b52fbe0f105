"""GLSL export of the multi-scale models (Timonen et al. 2025, Sec. 5.3: the model as a pixel shader).

`export_glsl(model)` turns a fitted `neumat.methods.latent_mlp.multiscale.MultiScale` (the gated model, its homogeneous
variant, and the configurations built on it: tripleplane, the ablations) into GLSL 3.30 source plus its
textures. The source defines

    vec3 neumat_eval(vec3 wi, vec3 wo, vec2 uv, mat2 footprint)   // spatially varying; footprint in uv^2
    vec3 neumat_eval_lod(vec3 wi, vec3 wo, vec2 uv, float lod)     // spatially varying; trilinear at lod
    vec3 neumat_eval(vec3 wi, vec3 wo)                             // homogeneous

Details: docs/formats/glsl.md, section `neumat.export.glsl`.
"""
from __future__ import annotations

from ..core.errors import InputError
from ..fit.method import load_methods
from .glsl_common import GLSLExport, read_as_images
from .half_precision import to_half
from .registry import EXPORT_FORMATS, ExportFormat


#: the export precisions: "fp16" (half textures and weights, float32 arithmetic; the default) and "fp32"
PRECISIONS = ("fp16", "fp32")


def export_glsl(model, precision: str = "fp16") -> GLSLExport:
    """GLSL source and textures computing `model.eval` (see module docstring). model: a MultiScale (or a
    configuration of it such as tripleplane), a neumip-family model (`neumat.methods.latent_mlp.glsl`, with the
    neural-appearance sampler), a NeuBRDF (`neumat.methods.neubrdf.glsl`), a SparseBTF
    (`neumat.methods.sparse_btf.glsl`) or a NeuPreSS translucent object
    (`neumat.methods.neupress.glsl`): any model whose method declares a GLSL generator (`glsl_models()`);
    anything else raises InputError. precision "fp16" stores textures and weights as halves
    (`neumat.export.half_precision`; textures a generator lists in `GLSLExport.exact` stay float32), "fp32" as
    floats. The textures the shader reads texel by texel are images under GLSL 4.20 and later
    (`neumat.export.glsl_common.read_as_images`)."""
    if precision not in PRECISIONS:
        raise InputError(f"export_glsl precision: expected one of {', '.join(PRECISIONS)}, got {precision!r}")
    name = getattr(model, "name", None)
    if not isinstance(name, str) or name not in glsl_models():
        raise InputError(f"export_glsl: expected a multi-scale model (multiscale, tripleplane), a latent-pyramid MLP "
                         f"(neumip, neumip-frame, neural-appearance), a neubrdf, a sparse-btf or a neupress, got "
                         f"{type(model).__name__} ({getattr(model, 'name', '?')})")
    exported = load_methods().get(name).glsl(model)
    return read_as_images(to_half(exported) if precision == "fp16" else exported)


def glsl_models() -> list[str]:
    """Names of the models whose method declares a GLSL generator (what `export_glsl` takes)."""
    methods = load_methods()
    return [name for name in methods.names() if methods.get(name).glsl is not None]


EXPORT_FORMATS.register("glsl")(ExportFormat("GLSL 3.30 source, textures and manifest.json", export_glsl))
