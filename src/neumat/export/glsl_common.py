"""Shared pieces of the GLSL exporters: `GLSLExport`, the common GLSL functions, texture packing, latent-pyramid
readers, shading frames and MLP chains.

A method declares its generator `glsl(model) -> GLSLExport` in its `neumat.fit.method.Method`;
`neumat.export.glsl.export_glsl` looks it up."""
from __future__ import annotations

import dataclasses
import json
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from ..core.errors import InputError

GLSL_VERSION = "#version 330 core"
"""The GLSL every export compiles under (WebGL 2's GLSL ES 3.00 too, and macOS's OpenGL 4.1)."""

GLSL_IMAGE_VERSION = "#version 420 core"
"""The GLSL from which an export reads its `GLSLExport.images` as images (OpenGL 4.2's image load / store)."""


def glsl_version_number(version: str) -> int:
    """The number of a #version line ("#version 420 core" -> 420); InputError for anything else."""
    parts = version.split() if isinstance(version, str) else []
    if len(parts) not in (2, 3) or parts[0] != "#version" or not parts[1].isdigit():
        raise InputError(f"glsl version: expected a #version line such as {GLSL_VERSION!r}, got {version!r}")
    return int(parts[1])


@dataclass
class GLSLExport:
    """GLSL source (without a #version line) and its textures: name -> array (layers, H, W, 4), float32, or
    float16 in an fp16 export (`neumat.export.half_precision.to_half`)."""

    source: str
    textures: dict[str, np.ndarray] = field(default_factory=dict)
    spatially_varying: bool = True
    entry: list[str] | None = None
    """The entry points the source defines (manifest.json); default those of `spatially_varying`."""
    precision: str = "fp32"
    """"fp32" (float textures, float constants) or "fp16" (half textures, weights as halves)."""
    exact: tuple[str, ...] = ()
    """Textures stored as float32 at every precision (index tables, fixed Fourier matrices, geometry, tables
    computed from the stored values)."""
    fp16_textures: dict[str, np.ndarray] = field(default_factory=dict)
    """Of the `exact` textures computed from stored values (NeuBRDF's first-layer table), their values when those
    are halves (computed in float32 from the half-rounded values, as `neumat.models.half_precision.half_rounded`):
    the fp16 form (`to_half`) stores these instead."""
    weight_values: int | None = None
    """Decoder weights in the source (set by `to_half`; an fp32 export counts its `const float` arrays)."""
    images: dict[str, int] = field(default_factory=dict)
    """Textures that the source reads with imageLoad, from this image unit, when compiled under
    `GLSL_IMAGE_VERSION` or later, and with texelFetch from a sampler2DArray below (`read_as_images`)."""

    def fastest_glsl_version(self) -> str:
        """The #version line this export runs fastest under: `GLSL_IMAGE_VERSION` where it has `images`, else
        `GLSL_VERSION` (under which every export runs)."""
        return GLSL_IMAGE_VERSION if self.images else GLSL_VERSION

    def entry_points(self) -> list[str]:
        """GLSL signatures of the entry points the source defines."""
        if self.entry:
            return list(self.entry)
        if self.spatially_varying:
            return ["vec3 neumat_eval(vec3 wi, vec3 wo, vec2 uv, mat2 footprint)",
                    "vec3 neumat_eval_lod(vec3 wi, vec3 wo, vec2 uv, float lod)"]
        return ["vec3 neumat_eval(vec3 wi, vec3 wo)"]

    def storage_bytes(self, precision: str | None = None) -> dict[str, int]:
        """Bytes of the textures and of the weights in the source, and their sum ({"textures", "weights",
        "total"}), at this export's precision or at `precision` ("fp16": 2 per value but for the `exact` textures,
        "fp32": 4 per value)."""
        precision = precision or self.precision
        weights = self.weight_values
        if weights is None:
            weights = sum(int(n) for n in re.findall(r"^const float \w+\[(\d+)\] = ", self.source, re.M))
        textures = sum(t.size * (2 if precision == "fp16" and name not in self.exact else 4)
                       for name, t in self.textures.items())
        weights *= 2 if precision == "fp16" else 4
        return {"textures": int(textures), "weights": int(weights), "total": int(textures + weights)}

    def summary(self, folder: Path) -> str:
        """What `write(folder)` wrote and its bytes at both precisions (`neumat export` prints it)."""
        sizes = {p: self.storage_bytes(p) for p in ("fp16", "fp32")}
        return (f"wrote {Path(folder) / 'neumat.glsl'} ({len(self.source)} characters) and {len(self.textures)} "
                f"textures to {folder}\nstored bytes: "
                + "; ".join(f"{p} {b['textures']} textures + {b['weights']} weights = {b['total']}"
                            for p, b in sizes.items())
                + (f" (fp16 / fp32 = {sizes['fp16']['total'] / sizes['fp32']['total']:.3f})" if sizes["fp32"]["total"]
                   else "") + f"; written: {self.precision}"
                + (f", float32 at both: {', '.join(self.exact)}" if self.exact else "")
                + (f"\ncompiles under {GLSL_VERSION}; fastest under {self.fastest_glsl_version()}, where "
                   + ", ".join(f"{name} is an image2DArray at image unit {unit}" for name, unit in self.images.items())
                   + " (manifest.json)" if self.images else ""))

    def write(self, folder: str | Path) -> Path:
        """Write neumat.glsl, one raw little-endian file per texture (<name>.f32, or <name>.f16 for a float16
        texture) and manifest.json (precision, bytes, textures and their formats) into `folder` (created);
        returns it."""
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        (folder / "neumat.glsl").write_text(self.source)
        manifest = {"source": "neumat.glsl", "glsl_version": GLSL_VERSION, "precision": self.precision,
                    "bytes": self.storage_bytes(), "textures": {}, "entry": self.entry_points()}
        if self.images:
            manifest["fastest_glsl_version"] = self.fastest_glsl_version()
        for name, data in self.textures.items():
            layers, height, width, _ = data.shape
            half = data.dtype == np.float16
            file = f"{name}.{'f16' if half else 'f32'}"
            data.astype("<f2" if half else "<f4").tofile(folder / file)
            manifest["textures"][name] = {"file": file, "target": "sampler2DArray",
                                          "format": "RGBA16F" if half else "RGBA32F",
                                          "width": width, "height": height, "layers": layers}
            if name in self.images:  # under GLSL_IMAGE_VERSION and later: an image2DArray at this unit
                manifest["textures"][name]["image_unit"] = self.images[name]
        (folder / "manifest.json").write_text(json.dumps(manifest, indent=2) + "\n")
        return folder


#: image uniforms a fragment shader may declare in any OpenGL 4.2 (GL_MAX_FRAGMENT_IMAGE_UNIFORMS' minimum)
MAX_IMAGES = 8


def read_as_images(export: GLSLExport) -> GLSLExport:
    """`export` with each of its textures that the source reads only as `texelFetch(name, p, 0)` (no filtering, no
    size query; the first MAX_IMAGES) declared twice: under `GLSL_IMAGE_VERSION` and later a read-only
    image2DArray (rgba32f, or rgba16f for a float16 texture) at its own image unit, read with imageLoad; below
    (GLSL 3.30, GLSL ES 3.00) the sampler2DArray it was, read with texelFetch; each read becomes
    `nm_texel_<name>(p)`. The units are in `images`. Why: llvmpipe's texelFetch runs its sampler's code (a
    called function of about 200 instructions for each fetch), its imageLoad a bounds-checked load: the
    shaders run up to 1.9x faster (docs/formats/glsl.md); every export keeps the GLSL 3.30 form."""
    source, images = export.source, dict(export.images)
    for name, data in export.textures.items():
        declaration = f"uniform sampler2DArray {name};"
        if len(images) == MAX_IMAGES or name in images or source.count(declaration) != 1:
            continue

        def fetch(args: list[str], name=name) -> str:
            if args[0] == name and len(args) == 3 and args[2] == "0":
                return f"nm_texel_{name}({args[1]})"
            return f"texelFetch({', '.join(args)})"
        rewritten = glsl_calls(source, "texelFetch", fetch)
        code = re.sub(r"//[^\n]*", "", rewritten).replace(declaration, "")
        if re.search(rf"\b{name}\b", code) is not None:  # read another way (textureSize, texture, a lod > 0)
            continue
        unit = len(images)
        images[name] = unit
        fmt = "rgba16f" if data.dtype == np.float16 else "rgba32f"
        source = rewritten.replace(declaration, f"""#if __VERSION__ >= {glsl_version_number(GLSL_IMAGE_VERSION)}
layout({fmt}, binding = {unit}) readonly uniform image2DArray {name};
vec4 nm_texel_{name}(ivec3 p) {{ return imageLoad({name}, p); }}
#else
uniform sampler2DArray {name};
vec4 nm_texel_{name}(ivec3 p) {{ return texelFetch({name}, p, 0); }}
#endif""")
    return dataclasses.replace(export, source=source, images=images)


def glsl_calls(src: str, name: str, rewrite) -> str:
    """`src` with every call `name(a, b, ...)` (`name` a regular expression) replaced by rewrite([a, b, ...])
    (top-level arguments, stripped)."""
    out, pos = [], 0
    pattern = re.compile(rf"\b{name}\s*\(")
    while (m := pattern.search(src, pos)) is not None:
        depth, args, start, i = 1, [], m.end(), m.end()
        while depth:
            c = src[i]
            if c in "([":
                depth += 1
            elif c in ")]":
                depth -= 1
            if (c == "," and depth == 1) or depth == 0:
                args.append(src[start:i].strip())
                start = i + 1
            i += 1
        out += [src[pos:m.start()], rewrite(args)]
        pos = i
    return "".join(out) + src[pos:]


def _floats(name: str, values: torch.Tensor) -> str:
    """`const float name[n] = float[](...);` of a tensor's values (row-major)."""
    flat = values.detach().double().flatten().cpu().numpy()
    if not np.isfinite(flat).all():
        raise InputError(f"export_glsl: parameter {name} has non-finite values; the model cannot be exported")
    body = ", ".join(f"{v:.9e}" for v in flat)
    return f"const float {name}[{len(flat)}] = float[]({body});"


def _layers(tex: torch.Tensor) -> np.ndarray:
    """(C, H, W) -> float32 (ceil(C / 4), H, W, 4), channel c in layer c // 4, component c % 4."""
    c, h, w = tex.shape
    layers = -(-c // 4)
    out = torch.zeros(layers * 4, h, w, dtype=torch.float64)
    out[:c] = tex.detach().double().cpu()
    out = out.view(layers, 4, h, w).permute(0, 2, 3, 1)
    if not torch.isfinite(out).all():
        raise InputError("export_glsl: a texture has non-finite values; the model cannot be exported")
    return out.float().contiguous().numpy()


def _atlas(levels: list[torch.Tensor]) -> tuple[np.ndarray, list[tuple[int, int]], list[tuple[int, int]]]:
    """Pyramid levels (C, h, w) -> atlas texture, level sizes (w, h) and origins (x, y)."""
    c, h0, w0 = levels[0].shape
    origins, top = [(0, 0)], 0
    for tex in levels[1:]:
        origins.append((w0, top))
        top += tex.shape[1]
    width = w0 + (max(t.shape[2] for t in levels[1:]) if len(levels) > 1 else 0)
    atlas = torch.zeros(c, max(h0, top), width, dtype=torch.float64)
    for tex, (x, y) in zip(levels, origins):
        atlas[:, y:y + tex.shape[1], x:x + tex.shape[2]] = tex.detach().double()
    return _layers(atlas), [(t.shape[2], t.shape[1]) for t in levels], origins


def _ivec2s(name: str, pairs: list[tuple[int, int]]) -> str:
    body = ", ".join(f"ivec2({a}, {b})" for a, b in pairs)
    return f"const ivec2 {name}[{len(pairs)}] = ivec2[]({body});"


_COMMON = """
float nm_softplus(float x) { return x > 20.0 ? x : (x < -15.0 ? exp(x) : log(1.0 + exp(x))); }
float nm_silu(float x) { return x / (1.0 + exp(-x)); }
vec4 nm_silu4(vec4 x) { return x / (1.0 + exp(-x)); }
vec4 nm_relu4(vec4 x) { return max(x, 0.0); }

// i modulo n for i in [-n, 2n) (GLSL leaves % of negative operands undefined)
int nm_wrap(int i, int n) { return i < 0 ? i + n : (i >= n ? i - n : i); }

vec3 nm_lift(vec3 w) { return vec3(w.xy, sqrt(max(1.0 - dot(w.xy, w.xy), 1e-10))); }

// Rusinkiewicz half and difference vectors (neumat.nn.angular_texture.half_difference)
void nm_half_difference(vec3 wi, vec3 wo, out vec3 h, out vec3 d) {
    h = wi + wo;
    h = h / max(length(h), 1e-12);
    float s2 = h.x * h.x + h.y * h.y;
    bool pole = s2 < 1e-14;
    float s = sqrt(pole ? 1.0 : s2);
    float cp = pole ? 1.0 : h.x / s, sp = pole ? 0.0 : h.y / s, st = pole ? 0.0 : s, ct = h.z;
    float x = cp * wi.x + sp * wi.y, y = -sp * wi.x + cp * wi.y;
    d = vec3(ct * x - st * wi.z, y, st * x + ct * wi.z);
}

// Duff et al. 2017 (neumat.core.frames.frame_from_normal)
void nm_basis(vec3 n, out vec3 t, out vec3 b) {
    float s = n.z >= 0.0 ? 1.0 : -1.0;
    float a = -1.0 / (s + n.z), c = n.x * n.y * a;
    t = vec3(1.0 + s * n.x * n.x * a, s * c, -s * n.x);
    b = vec3(c, s + n.y * n.y * a, -n.y);
}

// (r, phi) of the disk projection, phi in [0, period)
vec2 nm_disk_polar(vec3 w, float period) {
    float r2 = w.x * w.x + w.y * w.y;
    if (r2 < 1e-14) return vec2(0.0, 0.0);
    return vec2(min(sqrt(r2), 1.0), mod(atan(w.y, w.x), period));
}
"""


def _angular_reader(name: str, sampler: str, channels: int, radial: int, azimuths: int, period: float) -> str:
    """GLSL `void name(float r, float phi, out vec4 a[L])`: bilinear polar read (neumat.nn.angular_texture)."""
    layers = -(-channels // 4)
    return f"""
void {name}(float r, float phi, out vec4 a[{layers}]) {{
    float c = mod(phi, {period:.9e}) * {azimuths / period:.9e} - 0.5;
    float y = clamp(r, 0.0, 1.0) * {radial - 1}.0;
    float c0f = floor(c), r0f = floor(y);
    float fc = c - c0f, fr = y - r0f;
    int c0 = int(c0f), r0 = min(int(r0f), {radial - 1}), r1 = min(r0 + 1, {radial - 1});
    int c1 = nm_wrap(c0 + 1, {azimuths});
    c0 = nm_wrap(c0, {azimuths});
    int a0 = r0 == 0 ? 0 : c0, b0 = r0 == 0 ? 0 : c1;  // the pole row is texel (0, 0) for every azimuth
    for (int l = 0; l < {layers}; ++l) {{
        vec4 t00 = texelFetch({sampler}, ivec3(a0, r0, l), 0), t01 = texelFetch({sampler}, ivec3(b0, r0, l), 0);
        vec4 t10 = texelFetch({sampler}, ivec3(c0, r1, l), 0), t11 = texelFetch({sampler}, ivec3(c1, r1, l), 0);
        a[l] = mix(mix(t00, t01, fc), mix(t10, t11, fc), fr);
    }}
}}
"""


def _spatial_reader(model, roulette: bool = False) -> tuple[str, dict[str, np.ndarray]]:
    """GLSL of a model's spatial latent pyramid (`model.spatial`), see `pyramid_reader`."""
    with torch.no_grad():
        return pyramid_reader(model.spatial.levels(), model.spatial.max_probes, roulette)


def pyramid_reader(levels: list[torch.Tensor], max_probes: int | None, roulette: bool = False,
                   name: str = "spatial") -> tuple[str, dict[str, np.ndarray]]:
    """GLSL of a latent pyramid, levels (C, H_l, W_l), as the texture `neumat_spatial`:
    nm_spatial_lod(uv, lod, out z) (trilinear, `neumat.nn.latent_texture.trilinear`) and, unless max_probes
    is None, nm_spatial_footprint(uv, cov, out z) (`filter_anisotropic` with up to max_probes probes). With
    `roulette`, also the one-level reads of Russian-roulette level selection: nm_spatial_lod_level(uv, lod,
    which, out z, out t) and nm_spatial_footprint_level(uv, cov, which, out z, out t), which 0 for the finer and
    1 for the coarser of the two levels, t the coarser level's weight (`trilinear_flat` with level_u). A `name`
    other than "spatial" names a second pyramid beside it: the texture neumat_<name>, the functions nm_<name>_*
    and the constants NM_<NAME>_LEVEL* (NeuMIP's offset pyramid: nm_offset_lod, nm_offset_footprint)."""
    atlas, sizes, origins = _atlas(levels)
    layers, probes = atlas.shape[0], max_probes
    w0, h0 = sizes[0]
    src = f"""
uniform sampler2DArray neumat_spatial;
const int NM_LEVELS = {len(sizes)};
{_ivec2s("NM_LEVEL_SIZE", sizes)}
{_ivec2s("NM_LEVEL_ORIGIN", origins)}

vec4 nm_spatial_texel(int level, int x, int y, int layer) {{
    ivec2 s = NM_LEVEL_SIZE[level];
    ivec2 t = ivec2(nm_wrap(x, s.x), nm_wrap(y, s.y));
    return texelFetch(neumat_spatial, ivec3(NM_LEVEL_ORIGIN[level] + t, layer), 0);
}}

// weight x bilinear lookup (wrap tiling) of one level, added to z
void nm_spatial_bilinear(int level, vec2 uv, float weight, inout vec4 z[{layers}]) {{
    vec2 p = fract(uv);
    ivec2 s = NM_LEVEL_SIZE[level];
    float x = p.x * float(s.x) - 0.5, y = (1.0 - p.y) * float(s.y) - 0.5;
    float x0f = floor(x), y0f = floor(y);
    float fx = x - x0f, fy = y - y0f;
    int x0 = int(x0f), y0 = int(y0f);
    for (int l = 0; l < {layers}; ++l) {{
        vec4 top = mix(nm_spatial_texel(level, x0, y0, l), nm_spatial_texel(level, x0 + 1, y0, l), fx);
        vec4 bottom = mix(nm_spatial_texel(level, x0, y0 + 1, l), nm_spatial_texel(level, x0 + 1, y0 + 1, l), fx);
        z[l] += weight * mix(top, bottom, fy);
    }}
}}

void nm_spatial_trilinear(vec2 uv, float lod, float weight, inout vec4 z[{layers}]) {{
    lod = clamp(lod, 0.0, float(NM_LEVELS - 1));
    float lo = floor(lod);
    float t = lod - lo;
    int l0 = int(lo), l1 = min(int(lo) + 1, NM_LEVELS - 1);
    nm_spatial_bilinear(l0, uv, weight * (1.0 - t), z);
    nm_spatial_bilinear(l1, uv, weight * t, z);
}}

void nm_spatial_lod(vec2 uv, float lod, out vec4 z[{layers}]) {{
    for (int l = 0; l < {layers}; ++l) z[l] = vec4(0.0);
    nm_spatial_trilinear(uv, lod, 1.0, z);
}}
"""
    if roulette:
        src += f"""
// one of the two levels around lod (which 0: the finer, 1: the coarser), weight x bilinear, added to z
void nm_spatial_level(vec2 uv, float lod, int which, float weight, inout vec4 z[{layers}]) {{
    lod = clamp(lod, 0.0, float(NM_LEVELS - 1));
    int l0 = int(floor(lod));
    nm_spatial_bilinear(which == 0 ? l0 : min(l0 + 1, NM_LEVELS - 1), uv, weight, z);
}}

float nm_level_fraction(float lod) {{
    lod = clamp(lod, 0.0, float(NM_LEVELS - 1));
    return lod - floor(lod);
}}

void nm_spatial_lod_level(vec2 uv, float lod, int which, out vec4 z[{layers}], out float t) {{
    for (int l = 0; l < {layers}; ++l) z[l] = vec4(0.0);
    nm_spatial_level(uv, lod, which, 1.0, z);
    t = nm_level_fraction(lod);
}}
"""
    if max_probes is not None:
        variants = [("nm_spatial_footprint", "", "nm_spatial_trilinear(uv + offset * axis / scale, lod, 1.0 / n, z)",
                     "")]
        if roulette:
            variants.append(("nm_spatial_footprint_level", ", int which",
                             "nm_spatial_level(uv + offset * axis / scale, lod, which, 1.0 / n, z)",
                             ", out float t"))
        for function, which, probe, fraction in variants:
            src += _footprint_reader(function, which, probe, fraction, layers, probes, w0, h0)
    if name != "spatial":
        src = re.sub(r"\bneumat_spatial\b", f"neumat_{name}", src)
        src = re.sub(r"\bnm_spatial_", f"nm_{name}_", src)
        src = re.sub(r"\bnm_level_fraction\b", f"nm_{name}_level_fraction", src)
        src = re.sub(r"\bNM_LEVEL", f"NM_{name.upper()}_LEVEL", src)
    return src, {f"neumat_{name}": atlas}


def _footprint_reader(name: str, which: str, probe: str, fraction: str, layers: int, probes: int, w0: int,
                      h0: int) -> str:
    """GLSL of `name`(uv, cov[, which], out z[, out t]): the probes of `filter_anisotropic`, each read by `probe`."""
    t = "\n    t = nm_level_fraction(lod);" if fraction else ""
    return f"""
// anisotropic filtering of a Gaussian footprint (covariance in uv^2; neumat.nn.latent_texture)
void {name}(vec2 uv, mat2 cov{which}, out vec4 z[{layers}]{fraction}) {{
    for (int l = 0; l < {layers}; ++l) z[l] = vec4(0.0);
    vec2 scale = vec2({w0}.0, {h0}.0);
    float a = cov[0][0] * scale.x * scale.x, b = cov[1][0] * scale.x * scale.y, c = cov[1][1] * scale.y * scale.y;
    float mean = 0.5 * (a + c), half_gap = sqrt(0.25 * (a - c) * (a - c) + b * b);
    float theta = (b == 0.0 && a == c) ? 0.0 : 0.5 * atan(2.0 * b, a - c);
    float major = sqrt(max(mean + half_gap, 0.0)), minor = max(sqrt(max(mean - half_gap, 0.0)), 1e-12);
    vec2 axis = vec2(cos(theta), sin(theta));
    float n = clamp(ceil(major / minor), 1.0, {probes}.0);
    float sigma = max(minor, major / {probes}.0);
    float lod = log2(max(2.0 * sigma, 1e-12));{t}
    float spacing = sqrt(max(12.0 * (major * major - sigma * sigma), 0.0) / max(n * n - 1.0, 1.0));
    for (int k = 0; k < {probes}; ++k) {{
        if (float(k) >= n) break;
        float offset = (float(k) - 0.5 * (n - 1.0)) * spacing;
        {probe};
    }}
}}
"""


def shading_frames(frame, latent_dim: int, source: str) -> tuple[list[str], str]:
    """Constants and statements of a `neumat.nn.shading_frames.ShadingFrame` decoded from the latent `source`
    (an expression in i): wi and wo in every learned frame, lifted, as vec3 arrays di[frames], dw[frames]."""
    k = frame.frames
    consts = [_floats("NM_FRAME_W", frame.decode.weight * frame.weight_scale),
              _floats("NM_FRAME_B", frame.decode.bias)]
    code = f"    float v[{6 * k}];\n" + _linear("NM_FRAME", 6 * k, latent_dim, source, "v")
    code += f"""    vec3 di[{k}], dw[{k}];
    for (int k = 0; k < {k}; ++k) {{
        vec3 n = vec3(v[6 * k], v[6 * k + 1], v[6 * k + 2]);
        n = n / max(length(n), 1e-12);
        vec3 t = vec3(v[6 * k + 3], v[6 * k + 4], v[6 * k + 5]);
        t = t - dot(t, n) * n;
        t = t / max(length(t), 1e-12);
        vec3 bt = cross(n, t);
        di[k] = nm_lift(vec3(dot(wi, t), dot(wi, bt), dot(wi, n)));
        dw[k] = nm_lift(vec3(dot(wo, t), dot(wo, bt), dot(wo, n)));
    }}
"""
    return consts, code


def spatial_entry_points(layers: int) -> str:
    """GLSL of neumat_eval (footprint) and neumat_eval_lod around `nm_decode(wi, wo, z)`, z: `layers` vec4s of
    the filtered spatial latent; 0 below the horizon."""
    return f"""
vec3 neumat_eval(vec3 wi, vec3 wo, vec2 uv, mat2 footprint) {{
    if (wi.z <= 0.0 || wo.z <= 0.0) return vec3(0.0);
    vec4 z[{layers}];
    nm_spatial_footprint(uv, footprint, z);
    return nm_decode(wi, wo, z);
}}

vec3 neumat_eval_lod(vec3 wi, vec3 wo, vec2 uv, float lod) {{
    if (wi.z <= 0.0 || wo.z <= 0.0) return vec3(0.0);
    vec4 z[{layers}];
    nm_spatial_lod(uv, lod, z);
    return nm_decode(wi, wo, z);
}}
"""


def mlp_chain(prefix: str, mlp, source: str | list[str], activation: str) -> tuple[list[str], str, str]:
    """Constants (`<prefix><layer>_W / _B`), statements and the name of the output float array of an MLP
    (neumat.nn.mlp) whose input is `source` (an expression in i, or one expression per input: with constant i
    both arms of a conditional compile, so `[a if i < 3 else b for i in ...]` spells an input that picks its
    source by index), `activation` (a GLSL function of a float) after
    every hidden layer (its vec4 spelling `<activation>4` on the hidden groups: nm_silu4, nm_relu4 of `_COMMON`):
    `mlp_vec4` (unrolled, vec4 groups) of source at i = 0, 1, ..., the output copied into
    `float <prefix><last>[out]`."""
    layers = mlp.linears()
    inputs = list(source) if isinstance(source, list) else \
        [re.sub(r"\bi\b", str(i), source) for i in range(layers[0].in_features)]
    consts, body, outputs = mlp_vec4(prefix, mlp, inputs, f"{activation}4")
    out_dim, array = layers[-1].out_features, f"{prefix.lower()}{len(layers) - 1}"
    values = []
    for g, var in enumerate(outputs):
        size = min(4, out_dim - 4 * g)
        values += [var] if size == 1 else [f"{var}.{c}" for c in _SWIZZLE[:size]]
    body += f"    float {array}[{out_dim}] = float[]({', '.join(values)});\n"
    return consts, body, array


def _linear(name: str, out_dim: int, in_dim: int, source: str, target: str) -> str:
    """GLSL statements `target[o] = B[o] + sum_i W[o * in + i] * source(i)` (source: an expression in i)."""
    return f"""    for (int o = 0; o < {out_dim}; ++o) {{
        float acc = {name}_B[o];
        for (int i = 0; i < {in_dim}; ++i) acc += {name}_W[o * {in_dim} + i] * {source};
        {target}[o] = acc;
    }}
"""


_VEC = {1: "float", 2: "vec2", 3: "vec3", 4: "vec4"}
_SWIZZLE = "xyzw"


def vec4_components(names: list[str], count: int) -> list[str]:
    """The first `count` scalar components of the vec4 variables `names` (`["a.x", "a.y", ...]`)."""
    out = [f"{name}.{c}" for name in names for c in _SWIZZLE][:count]
    if len(out) < count:
        raise ValueError(f"vec4_components: {len(names)} vec4s hold fewer than {count} components")
    return out


def dense_vec4(name: str, weight: torch.Tensor, inputs: list[str], target: str, bias: torch.Tensor | None = None,
               init: list[str] | None = None, pad: bool = False) -> tuple[list[str], str, list[str]]:
    """Constants, statements and output variables of `y = W x (+ b | + init)`, unrolled and vectorised: outputs in
    groups of 4 (`vec4 <target>_<g>`; a last group of fewer outputs is a float / vec2 / vec3), each the sum of one
    vecN product per input, `x_i * vecN(W[o, i], W[o + 1, i], ...)`, read from `const float <name>_W[out * in]`
    (row-major, as `mlp_chain`) with constant indices, so that the compiler folds them into immediates
    (`half_precision.to_half` packs the array as halves; the constant reads of those fold too). `inputs`: one
    scalar GLSL expression per input column. The start of each group is `init[g]` (a vec4 expression, swizzled to
    the group's size) if given, else the bias `const float <name>_B[out]` (or 0). `pad`: every group a vec4, the
    missing outputs 0."""
    out_dim, in_dim = weight.shape
    if len(inputs) != in_dim:
        raise ValueError(f"dense_vec4 {name}: {len(inputs)} inputs for a {out_dim} x {in_dim} matrix")
    consts = [_floats(f"{name}_W", weight)] if in_dim else []
    if bias is not None and init is None:
        consts.append(_floats(f"{name}_B", bias))
    code, outputs = "", []
    for g, o0 in enumerate(range(0, out_dim, 4)):
        rows = list(range(o0, min(o0 + 4, out_dim)))
        vec = _VEC[4 if pad else len(rows)]
        zeros = [] if vec == _VEC[len(rows)] else ["0.0"] * (4 - len(rows))
        if init is not None:  # a vec4 expression; fewer outputs read its first components
            start = init[g] if vec == "vec4" else f"({init[g]}).{_SWIZZLE[:len(rows)]}"
        elif bias is not None:
            start = f"{vec}({', '.join([f'{name}_B[{o}]' for o in rows] + zeros)})"
        else:
            start = f"{vec}(0.0)"
        terms = [start] + [f"{x} * {vec}({', '.join([f'{name}_W[{o * in_dim + i}]' for o in rows] + zeros)})"
                           for i, x in enumerate(inputs)]
        var = f"{target}_{g}"
        code += f"    {vec} {var} = " + "\n        + ".join(terms) + ";\n"
        outputs.append(var)
    return consts, code, outputs


def mlp_vec4(prefix: str, mlp, inputs: list[str], activation: str, first_init: list[str] | None = None,
             first_columns: slice | None = None) -> tuple[list[str], str, list[str]]:
    """`mlp_chain` unrolled and vectorised (`dense_vec4` per layer): constants `<prefix><layer>_W / _B`, statements,
    and the output variables (vec4 groups; the last a float / vec2 / vec3 when the output size is not a multiple of
    4). `inputs`: one scalar expression per input; `activation`: a GLSL function of a vec4 applied to every hidden
    group (hidden groups are vec4s, padded outputs are 0 before the activation and never read). `first_init`,
    `first_columns`: the first layer starts from `first_init` (one vec4 expression per group, e.g. a lookup table's
    pre-activations, bias included) and reads only the weight columns `first_columns` (those of `inputs`)."""
    consts, body, xs = [], "", list(inputs)
    layers = mlp.linears()
    outputs: list[str] = []
    for l, layer in enumerate(layers):
        name, var = f"{prefix}{l}", f"{prefix.lower()}{l}"
        weight, bias, init = layer.weight.detach(), layer.bias.detach(), None
        if l == 0 and first_columns is not None:
            weight = weight[:, first_columns]
            init = first_init
        hidden = l < len(layers) - 1
        c, code, outputs = dense_vec4(name, weight, xs, var, bias, init, pad=hidden)
        consts += c
        body += code
        if hidden:
            body += "".join(f"    {v} = {activation}({v});\n" for v in outputs)
            xs = vec4_components(outputs, layer.out_features)
    return consts, body, outputs
