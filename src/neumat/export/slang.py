"""Slang export of the latent-pyramid + MLP models (neumip, neumip-offset, neumip-frame, neural-appearance), the
multi-scale models, NeuBRDF, SparseBTF and NeuPreSS: one shader module per neural material implementing a fixed
interface, as the runtime of Real-Time Neural Appearance Models (Zeltner et al. 2024, Sec. 7) generates for the
Slang shading language.

`export_slang(model) -> SlangExport`: interfaces `INeumatMaterial`, `INeumatSampler`, `INeumatAlbedo`,
`INeumatBRDF`, `INeumatTranslucent`, `INeumatTranslucentShade` and the compute entry point `neumat_batch`;
the module is the model's GLSL export spelled in Slang (`glsl_to_slang`). `SlangExport.write(folder)` writes
`neumat.slang`, its buffers and `manifest.json`.

Details: docs/formats/slang.md, section `neumat.export.slang`.
"""
from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..core.errors import InputError
from .glsl import glsl_models
from .glsl_common import GLSLExport, glsl_calls
from .registry import EXPORT_FORMATS, ExportFormat, load_formats

#: floats per query in the compute entry point's input buffer `neumat_queries` (offsets in QUERY_LAYOUT)
QUERY_FLOATS = 23
QUERY_LAYOUT = {"wi": 0, "wo": 3, "uv": 6, "lod": 8, "footprint_xx_xy_yy": 9, "u": 12, "x": 14, "n": 17, "alpha": 20,
                "ior": 21, "samples": 22}
#: floats per query in the output buffer `neumat_results`: rgb (eval, eval_lod, albedo), wo (sample), pdf in 0
RESULT_FLOATS = 4
#: threads per group of `neumat_batch`
GROUP_SIZE = 64
#: the compute entry point's query kinds (`neumat_entry`)
ENTRY_CODES = {"eval": 0, "eval_lod": 1, "albedo": 2, "sample": 3, "pdf": 4, "eval_brdf": 5, "translucent": 6,
               "sigma": 7, "sample_incident": 8, "incident_pdf": 9, "shade": 10, "rough_dielectric_reflection": 11}
#: GLSL entry-point signature (`GLSLExport.entry_points`) -> method of NeumatMaterial
_GLSL_ENTRIES = {
    "vec3 neumat_eval(vec3 wi, vec3 wo, vec2 uv, mat2 footprint)": "eval",
    "vec3 neumat_eval_lod(vec3 wi, vec3 wo, vec2 uv, float lod)": "eval_lod",
    "vec3 neumat_albedo(vec3 wi, vec3 wo, vec2 uv, mat2 footprint)": "albedo",
    "vec3 neumat_sample(vec3 wi, vec2 uv, mat2 footprint, vec2 u)": "sample",
    "float neumat_pdf(vec3 wi, vec3 wo, vec2 uv, mat2 footprint)": "pdf",
    "vec3 neumat_eval(vec3 wi, vec3 wo)": "eval_brdf",
    "vec3 neumat_translucent(vec3 wi, vec3 x, vec3 wo)": "translucent",
    "float neumat_sigma(vec3 x, vec3 wo)": "sigma",
    "vec3 neumat_sample_incident(vec3 x, vec3 wo, vec3 n, vec2 u)": "sample_incident",
    "float neumat_incident_pdf(vec3 wi, vec3 x, vec3 wo, vec3 n)": "incident_pdf",
    "vec3 neumat_translucent_shade(vec3 x, vec3 n, vec3 wo, float alpha, float ior, int samples)": "shade",
    "float neumat_rough_dielectric_reflection(vec3 n, vec3 wo, vec3 wi, float alpha, float ior)":
        "rough_dielectric_reflection",
}
#: method of NeumatMaterial -> the module's free function it calls, where not neumat_<method>
_FREE_FUNCTIONS = {"eval_brdf": "neumat_eval", "shade": "neumat_translucent_shade"}

_SIGNATURES = {
    "eval": "float3 eval(float3 wi, float3 wo, float2 uv, float2x2 footprint)",
    "eval_lod": "float3 eval_lod(float3 wi, float3 wo, float2 uv, float lod)",
    "albedo": "float3 albedo(float3 wi, float3 wo, float2 uv, float2x2 footprint)",
    "sample": "float3 sample(float3 wi, float2 uv, float2x2 footprint, float2 u)",
    "pdf": "float pdf(float3 wi, float3 wo, float2 uv, float2x2 footprint)",
    "eval_brdf": "float3 eval(float3 wi, float3 wo)",
    "translucent": "float3 translucent(float3 wi, float3 x, float3 wo)",
    "sigma": "float sigma(float3 x, float3 wo)",
    "sample_incident": "float3 sample_incident(float3 x, float3 wo, float3 n, float2 u)",
    "incident_pdf": "float incident_pdf(float3 wi, float3 x, float3 wo, float3 n)",
    "shade": "float3 shade(float3 x, float3 n, float3 wo, float alpha, float ior, int samples)",
    "rough_dielectric_reflection": "float rough_dielectric_reflection(float3 n, float3 wo, float3 wi, float alpha, "
                                   "float ior)",
}
#: interface -> (base clause, methods); NeumatMaterial implements those whose methods the model has
_INTERFACES = {"INeumatMaterial": ("", ("eval", "eval_lod")),
               "INeumatSampler": (" : INeumatMaterial", ("sample", "pdf")),
               "INeumatAlbedo": ("", ("albedo",)),
               "INeumatBRDF": ("", ("eval_brdf",)),
               "INeumatTranslucent": ("", ("translucent", "sigma", "sample_incident", "incident_pdf")),
               "INeumatTranslucentShade": (" : INeumatTranslucent", ("shade", "rough_dielectric_reflection"))}


@dataclass
class SlangExport:
    """Slang module source and its buffers: name -> array (layers, H, W, 4), float32 bound as
    `StructuredBuffer<float4>` or float16 (an fp16 export) bound as `StructuredBuffer<uint2>` (the four halves of
    a texel in two words), of layers * H * W elements. entries: the methods of `NeumatMaterial` (keys of
    ENTRY_CODES). bytes: `GLSLExport.storage_bytes` of the export it spells. runtime_buffers: buffers the caller
    binds with their `<name>_width`, `<name>_height` (a neupress export's environment `neumat_env`;
    `environment_bindings`)."""

    source: str
    buffers: dict[str, np.ndarray] = field(default_factory=dict)
    entries: list[str] = field(default_factory=list)
    interfaces: list[str] = field(default_factory=list)
    model: str = ""
    precision: str = "fp32"
    bytes: dict[str, int] = field(default_factory=dict)
    runtime_buffers: list[str] = field(default_factory=list)

    def entry_points(self) -> list[str]:
        """Slang signatures of the methods of `NeumatMaterial`."""
        return [_SIGNATURES[e] for e in self.entries]

    def summary(self, folder: Path) -> str:
        """What `write(folder)` wrote (`neumat export` prints it)."""
        return (f"wrote {Path(folder) / 'neumat.slang'} ({len(self.source)} characters), {len(self.buffers)} "
                f"buffer(s) and manifest.json to {folder}")

    def write(self, folder: str | Path) -> Path:
        """Write neumat.slang, one raw little-endian file per buffer (<buffer>.f16 for float16, <buffer>.f32 for
        float32) and manifest.json into `folder` (created); returns it."""
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        (folder / "neumat.slang").write_text(self.source)
        manifest = {
            "source": "neumat.slang", "language": "slang", "model": self.model, "struct": "NeumatMaterial",
            "precision": self.precision, "bytes": self.bytes,
            "interfaces": self.interfaces, "entry": self.entry_points(), "buffers": {},
            "runtime_buffers": {name: {"type": "StructuredBuffer<float4>", "width": f"{name}_width",
                                       "height": f"{name}_height", "order": "row, column",
                                       "content": "equirectangular linear RGB radiance (neumat.render.envmaps)"}
                                for name in self.runtime_buffers},
            "compute": {"entry": "neumat_batch", "numthreads": [GROUP_SIZE, 1, 1],
                        "queries": "neumat_queries", "results": "neumat_results", "count": "neumat_count",
                        "kind": "neumat_entry", "kinds": {e: ENTRY_CODES[e] for e in self.entries},
                        "query_floats": QUERY_FLOATS, "query_layout": QUERY_LAYOUT, "result_floats": RESULT_FLOATS},
        }
        for name, data in self.buffers.items():
            layers, height, width, _ = data.shape
            half = data.dtype == np.float16
            file = f"{name}.{'f16' if half else 'f32'}"
            data.astype("<f2" if half else "<f4").tofile(folder / file)
            manifest["buffers"][name] = {"file": file,
                                         "type": "StructuredBuffer<uint2>" if half else "StructuredBuffer<float4>",
                                         "elements": layers * height * width, "width": width, "height": height,
                                         "layers": layers, "order": "layer, row, column"}
        (folder / "manifest.json").write_text(json.dumps(manifest, indent=2) + "\n")
        return folder


def environment_bindings(radiance: np.ndarray) -> dict:
    """The globals a neupress module's `shade` reads, for an equirectangular environment `radiance` (H, W, 3) or
    (H, W, 4) linear RGB (the mapping of `neumat.render.envmaps`, row 0 at +y): {"neumat_env": (H * W, 4)
    float32 (rows, then columns; the data of its StructuredBuffer<float4>), "neumat_env_width": W,
    "neumat_env_height": H}."""
    radiance = np.asarray(radiance)
    if radiance.ndim != 3 or radiance.shape[2] not in (3, 4) or radiance.shape[0] < 1 or radiance.shape[1] < 1:
        raise InputError(f"environment_bindings radiance: expected an (H, W, 3) or (H, W, 4) array, got shape "
                         f"{radiance.shape}")
    height, width = radiance.shape[:2]
    texels = np.zeros((height * width, 4), np.float32)
    texels[:, :3] = radiance[..., :3].reshape(-1, 3)
    texels[:, 3] = 1.0
    return {"neumat_env": texels, "neumat_env_width": width, "neumat_env_height": height}


# ------------------------------------------------------------------------------ GLSL -> Slang
_TYPES = {"vec2": "float2", "vec3": "float3", "vec4": "float4", "ivec2": "int2", "ivec3": "int3", "ivec4": "int4",
          "mat2": "float2x2"}
# GLSL mod floors; Slang's fmod truncates
_FUNCTIONS = {"mix": "lerp", "fract": "frac", "mod": "nm_mod", "uintBitsToFloat": "asfloat"}
_LEFTOVER = re.compile(r"\b(i?vec[234]|mat[234]|texelFetch|texture\w*|sampler\w*|uniform|dFd[xy]|inversesqrt)\b"
                       r"|\b(mix|fract|mod)\s*\(|\w\[\]\(")

_PRELUDE = """
// GLSL's mod: x - y floor(x / y) (Slang's fmod truncates)
float nm_mod(float x, float y) { return x - y * floor(x / y); }
"""


def glsl_to_slang(source: str, textures: dict[str, np.ndarray], runtime: tuple[str, ...] = ()) -> str:
    """Slang spelling of GLSL `source` in the subset the neumat GLSL generators emit: vector / matrix types,
    mix / fract / two-argument atan / mod, `const T name[n] = T[](...)` arrays and local `T[](...)` array
    initialisers, and `sampler2DArray` textures
    (`textures`: name -> (layers, H, W, 4)) read with `texelFetch(name, ivec3(x, y, layer), 0)`, which become
    `StructuredBuffer<float4>` globals read by index. `runtime`: names of one-layer float textures whose size is
    known only at run time (the environment of a neupress export): each becomes a `StructuredBuffer<float4>`
    (rows x columns) with `uniform int <name>_width, <name>_height`, which `textureSize(name, 0)` reads. Raises
    RuntimeError if GLSL spellings remain (a generator that emits something this rewrite does not know). A block
    `#if __VERSION__ >= N ... #else ... #endif` (`neumat.export.glsl_common.read_as_images`) keeps its #else side:
    its texelFetch form."""
    src = re.sub(r"^#if __VERSION__ >= \d+\n.*?^#else\n(.*?)^#endif\n", r"\1", source, flags=re.M | re.S)
    src = re.sub(r"^const (\w+) (\w+)\[(\d+)\] = \1\[\]\((.*)\);$", r"static const \1 \2[\3] = { \4 };", src,
                 flags=re.M)
    src = re.sub(r"^const ", "static const ", src, flags=re.M)
    for name, data in textures.items():
        layers, height, width, _ = data.shape
        at = f"(p.z * {height} + p.y) * {width} + p.x"
        if data.dtype == np.float16:  # four halves in two words (x in the low bits of the first)
            declaration = f"""StructuredBuffer<uint2> {name};  // {layers} layers x {height} rows x {width} columns, \
RGBA halves
float4 nm_fetch_{name}(int3 p) {{
    uint2 h = {name}[{at}];
    return float4(nm_half(h.x & 65535u), nm_half(h.x >> 16u), nm_half(h.y & 65535u), nm_half(h.y >> 16u));
}}"""
        else:
            declaration = f"""StructuredBuffer<float4> {name};  // {layers} layers x {height} rows x {width} columns
float4 nm_fetch_{name}(int3 p) {{ return {name}[{at}]; }}"""
        src = src.replace(f"uniform sampler2DArray {name};", declaration)
    for name in runtime:
        src = src.replace(f"uniform sampler2DArray {name};", f"""StructuredBuffer<float4> {name};  // rows x columns, \
bound at run time
uniform int {name}_width;
uniform int {name}_height;
float4 nm_fetch_{name}(int3 p) {{ return {name}[p.y * {name}_width + p.x]; }}""")
        src = src.replace(f"textureSize({name}, 0)", f"int3({name}_width, {name}_height, 1)")

    def fetch(args: list[str]) -> str:
        if len(args) != 3 or (args[0] not in textures and args[0] not in runtime) or args[2] != "0":
            raise RuntimeError(f"glsl_to_slang: unsupported texelFetch({', '.join(args)})")
        return f"nm_fetch_{args[0]}({args[1]})"

    for name, data in textures.items():  # a layer count used as an opaque loop bound (Mesa compile time)
        src = src.replace(f"textureSize({name}, 0).z", str(data.shape[0]))
    src = glsl_calls(src, "texelFetch", fetch)
    # local array initialisers T[](a, b, ...) -> { a, b, ... }
    src = glsl_calls(src, r"(?:float|int|i?vec[234])\[\]", lambda args: "{ " + ", ".join(args) + " }")
    src = glsl_calls(src, "atan", lambda args: f"{'atan2' if len(args) == 2 else 'atan'}({', '.join(args)})")
    for glsl, slang in _TYPES.items():
        src = re.sub(rf"\b{glsl}\b", slang, src)
    for glsl, slang in _FUNCTIONS.items():
        src = re.sub(rf"\b{glsl}(?=\s*\()", slang, src)
    code = re.sub(r"//[^\n]*", "", src)
    for name in runtime:  # the size uniforms written above
        code = re.sub(rf"^uniform int {name}_(width|height);$", "", code, flags=re.M)
    if (m := _LEFTOVER.search(code)) is not None:
        raise RuntimeError(f"glsl_to_slang: GLSL spelling {m.group(0)!r} left in the Slang source")
    return _PRELUDE + src


# ------------------------------------------------------------------------------ the Slang-only parts
def _interfaces() -> str:
    out = []
    for name, (base, methods) in _INTERFACES.items():
        body = "".join(f"    {_SIGNATURES[m]};\n" for m in methods)
        out.append(f"interface {name}{base} {{\n{body}}}\n")
    return "\n".join(out)


def _material(entries: list[str], interfaces: list[str]) -> str:
    methods = ""
    for e in entries:
        args = re.findall(r"(\w+)(?:,|\))", _SIGNATURES[e])  # parameter names, in order
        function = _FREE_FUNCTIONS.get(e, f"neumat_{e}")
        methods += f"    {_SIGNATURES[e]} {{ return {function}({', '.join(args)}); }}\n"
    return f"""
/// The exported material: stateless; its latent pyramid is the global buffer neumat_spatial.
struct NeumatMaterial : {', '.join(interfaces)} {{
{methods}}}
"""


def _kernel(entries: list[str]) -> str:
    calls = {
        "eval": "float4(m.eval(wi, wo, uv, footprint), 1.0)",
        "eval_lod": "float4(m.eval_lod(wi, wo, uv, lod), 1.0)",
        "albedo": "float4(m.albedo(wi, wo, uv, footprint), 1.0)",
        "sample": "float4(m.sample(wi, uv, footprint, u), 1.0)",
        "pdf": "float4(m.pdf(wi, wo, uv, footprint), 0.0, 0.0, 1.0)",
        "eval_brdf": "float4(m.eval(wi, wo), 1.0)",
        "translucent": "float4(m.translucent(wi, x, wo), 1.0)",
        "sigma": "float4(m.sigma(x, wo), 0.0, 0.0, 1.0)",
        "sample_incident": "float4(m.sample_incident(x, wo, n, u), 1.0)",
        "incident_pdf": "float4(m.incident_pdf(wi, x, wo, n), 0.0, 0.0, 1.0)",
        "shade": "float4(m.shade(x, n, wo, alpha, ior, samples), 1.0)",
        "rough_dielectric_reflection": "float4(m.rough_dielectric_reflection(n, wo, wi, alpha, ior), 0.0, 0.0, 1.0)",
    }
    cases = "".join(f"    case {ENTRY_CODES[e]}: r = {calls[e]}; break;\n" for e in entries)
    lay = QUERY_LAYOUT
    f = lay["footprint_xx_xy_yy"]
    return f"""
// ---- batch evaluation (tests, examples): {QUERY_FLOATS} floats per query in neumat_queries
//   wi {lay['wi']}..{lay['wi'] + 2}, wo {lay['wo']}..{lay['wo'] + 2}, uv {lay['uv']}..{lay['uv'] + 1}, \
lod {lay['lod']}, footprint (xx, xy, yy) {f}..{f + 2}, u {lay['u']}..{lay['u'] + 1}, x {lay['x']}..{lay['x'] + 2}, \
n {lay['n']}..{lay['n'] + 2}, alpha {lay['alpha']}, ior {lay['ior']}, samples {lay['samples']}
// results: {RESULT_FLOATS} floats per query (rgb, a direction, or the pdf / sigma in the first); neumat_entry picks
// the method:
// {', '.join(f'{e} {ENTRY_CODES[e]}' for e in entries)}
StructuredBuffer<float> neumat_queries;
RWStructuredBuffer<float> neumat_results;
uniform uint neumat_count;
uniform int neumat_entry;

[shader("compute")]
[numthreads({GROUP_SIZE}, 1, 1)]
void neumat_batch(uint3 tid: SV_DispatchThreadID) {{
    uint i = tid.x;
    if (i >= neumat_count) return;
    uint b = i * {QUERY_FLOATS};
    float3 wi = float3(neumat_queries[b + {lay['wi']}], neumat_queries[b + {lay['wi'] + 1}], \
neumat_queries[b + {lay['wi'] + 2}]);
    float3 wo = float3(neumat_queries[b + {lay['wo']}], neumat_queries[b + {lay['wo'] + 1}], \
neumat_queries[b + {lay['wo'] + 2}]);
    float2 uv = float2(neumat_queries[b + {lay['uv']}], neumat_queries[b + {lay['uv'] + 1}]);
    float lod = neumat_queries[b + {lay['lod']}];
    float xx = neumat_queries[b + {f}], xy = neumat_queries[b + {f + 1}], yy = neumat_queries[b + {f + 2}];
    float2x2 footprint = float2x2(xx, xy, xy, yy);
    float2 u = float2(neumat_queries[b + {lay['u']}], neumat_queries[b + {lay['u'] + 1}]);
    float3 x = float3(neumat_queries[b + {lay['x']}], neumat_queries[b + {lay['x'] + 1}], \
neumat_queries[b + {lay['x'] + 2}]);
    float3 n = float3(neumat_queries[b + {lay['n']}], neumat_queries[b + {lay['n'] + 1}], \
neumat_queries[b + {lay['n'] + 2}]);
    float alpha = neumat_queries[b + {lay['alpha']}], ior = neumat_queries[b + {lay['ior']}];
    int samples = int(neumat_queries[b + {lay['samples']}]);
    NeumatMaterial m;
    float4 r = float4(0.0);
    switch (neumat_entry) {{
{cases}    default: break;
    }}
    for (int k = 0; k < {RESULT_FLOATS}; ++k) neumat_results[i * {RESULT_FLOATS} + k] = r[k];
}}
"""


def export_slang(model, precision: str = "fp16") -> SlangExport:
    """Slang module and buffers of a neumip-family model (neumip, neumip-frame, neural-appearance), a multi-scale
    model (multiscale, tripleplane and the other configurations `export_glsl` takes), a NeuBRDF, a SparseBTF or
    a NeuPreSS (module docstring). Anything else raises InputError naming the model type. precision: that of
    the GLSL export it spells ("fp16": half buffers and weights, float32 arithmetic; or "fp32")."""
    name = getattr(model, "name", None)
    if not isinstance(name, str) or name not in glsl_models():
        raise InputError(f"export_slang: expected a latent-pyramid MLP (neumip, neumip-frame, neural-appearance), a "
                         f"multi-scale model, a neubrdf, a sparse-btf or a neupress, got {type(model).__name__} "
                         f"({getattr(model, 'name', '?')})")
    directions = getattr(getattr(model, "cfg", None), "directions", "cartesian")  # the neumip family's inputs
    if directions != "cartesian":
        raise InputError(f"export_slang: {model.name} with {directions!r} directions has no Slang export "
                         "(cartesian only)")
    return slang_from_glsl(load_formats().get("glsl").export(model, precision), model.name)


def slang_from_glsl(glsl: GLSLExport, name: str) -> SlangExport:
    """The Slang module and buffers that spell a GLSL export (named `name` in its header and manifest): the body
    translated (`glsl_to_slang`), `NeumatMaterial` with the methods the GLSL entry points provide, and
    `neumat_batch`. Also how the speed suite builds Slang GGX and its harness floor from their GLSL."""
    entries = [e for e in ENTRY_CODES if e in {_GLSL_ENTRIES.get(sig) for sig in glsl.entry_points()}]
    interfaces = [iface for iface, (_, methods) in _INTERFACES.items() if set(methods) <= set(entries)]
    # textures the export declares but does not carry (a neupress export's environment) are bound at run time
    runtime = tuple(t for t in re.findall(r"^uniform sampler2DArray (\w+);", glsl.source, flags=re.M)
                    if t not in glsl.textures)
    body = glsl_to_slang(glsl.source.split("\n", 1)[1], glsl.textures, runtime)
    header = (f"// neumat Slang module of a '{name}' model (methods: {', '.join(entries)}); see "
              "neumat.export.slang.\n// Bind the StructuredBuffer<float4> globals listed in manifest.json"
              + "".join(f", and {t} with {t}_width, {t}_height at run time" for t in runtime) + ".\n")
    source = header + body + "\n" + _interfaces() + _material(entries, interfaces) + _kernel(entries)
    return SlangExport(source, dict(glsl.textures), entries, interfaces, name, glsl.precision,
                       glsl.storage_bytes(), list(runtime))


EXPORT_FORMATS.register("slang")(ExportFormat("Slang module, its buffers and manifest.json", export_slang,
                                              folder="slang"))
