"""GLSL export of the latent-pyramid + MLP models (`neumat.methods.latent_mlp.neumip` family: neumip, neumip-offset,
neumip-frame, neural-appearance), the shader runtime of Real-Time Neural Appearance Models (Zeltner et al. 2024,
Sec. 7).

Entry points: `neumat_eval`, `neumat_eval_lod` and, for neural-appearance, `neumat_albedo`, `neumat_lobes`,
`neumat_sample`, `neumat_pdf`; the pyramid is one `sampler2DArray` atlas (`neumat_spatial`).

Details: docs/formats/glsl.md, section `neumat.methods.latent_mlp.glsl`.
"""
from __future__ import annotations

import math

import numpy as np
import torch

from neumat.core.errors import InputError
from neumat.methods.latent_mlp.neumip import NeuMIP
from neumat.warp.microfacet_proxy import MAX_RHO, MIN_ALPHA
from neumat.export.glsl_common import (_COMMON, GLSLExport, _spatial_reader, mlp_chain, pyramid_reader,
                          shading_frames, spatial_entry_points)


_SAMPLING = """
float nm_relu(float x) { return max(x, 0.0); }
float nm_soft_tanh(float x) { float c = clamp(x, -2.0, 2.0); return c * (1.0 - abs(c) / 4.0); }
float nm_soft_sinh(float x) { return x * (1.0 + abs(x) / 2.0); }

// concentric disk, lifted (neumat.warp.hemisphere.sample_cosine_hemisphere)
vec3 nm_cosine(vec2 u) {
    float a = 2.0 * u.x - 1.0, b = 2.0 * u.y - 1.0;
    bool first = abs(a) > abs(b);
    float r = first ? a : b;
    float phi = first ? 0.785398163 * b / (a == 0.0 ? 1.0 : a) : 1.570796327 - 0.785398163 * a / (b == 0.0 ? 1.0 : b);
    vec2 p = r * vec2(cos(phi), sin(phi));
    return vec3(p, sqrt(max(1.0 - dot(p, p), 0.0)));
}

struct NmLobes { float wd; vec2 mud; vec2 alpha; float rho; vec2 mus; };

vec3 nm_diffuse_normal(NmLobes p) { return normalize(vec3(-p.mud, 1.0)); }

vec3 nm_apply_m(NmLobes p, vec3 v) {
    float s = sqrt(1.0 - p.rho * p.rho);
    return vec3(p.alpha.x * v.x - p.mus.x * v.z, p.alpha.y * p.rho * v.x + p.alpha.y * s * v.y - p.mus.y * v.z, v.z);
}

float nm_proxy_pdf(NmLobes p, vec3 wi, vec3 wo) {
    float pd = max(dot(wo, nm_diffuse_normal(p)), 0.0) / 3.141592654;
    vec3 h = wi + wo;
    if (h.z < 0.0) h = -h;
    float len = length(h);
    float ps = 0.0;
    if (len > 1e-12 && h.z > 0.0) {
        h /= len;
        float s = sqrt(1.0 - p.rho * p.rho);
        float px = h.x + p.mus.x * h.z, py = h.y + p.mus.y * h.z;
        float x = px / p.alpha.x;
        vec3 v = vec3(x, (py - p.alpha.y * p.rho * x) / (p.alpha.y * s), h.z);
        float r = length(v);
        float ph = (v.z / r) / 3.141592654 / (p.alpha.x * p.alpha.y * s) / (r * r * r);
        float c = abs(dot(wo, h));
        if (c > 0.0) ps = ph / (4.0 * max(c, 1e-12));
    }
    return p.wd * pd + (1.0 - p.wd) * ps;
}

vec3 nm_proxy_sample(NmLobes p, vec3 wi, vec2 u) {
    bool diffuse = u.x < p.wd;
    float u0 = diffuse ? u.x / max(p.wd, 1e-12) : (u.x - p.wd) / max(1.0 - p.wd, 1e-12);
    vec3 local = nm_cosine(vec2(clamp(u0, 0.0, 1.0 - 1e-7), u.y));
    if (diffuse) {
        vec3 n = nm_diffuse_normal(p), t, b;
        nm_basis(n, t, b);
        return local.x * t + local.y * b + local.z * n;
    }
    vec3 h = normalize(nm_apply_m(p, local));
    return 2.0 * dot(wi, h) * h - wi;
}
"""


def _two_level(layers: int, read: str, where: str, decode: str) -> str:
    """GLSL statements returning the Russian-roulette expectation (1 - t) decode(z_finer) + t decode(z_coarser),
    the two latents read by `read`(`where`, which, z, t) (`pyramid_reader` with roulette), as
    `NeuMIP.filtered_outputs`."""
    return f"""    vec4 z0[{layers}], z1[{layers}];
    float t;
    {read}({where}, 0, z0, t);
    {read}({where}, 1, z1, t);
    return (1.0 - t) * {decode}(wi, wo, z0) + t * {decode}(wi, wo, z1);"""


def _entry_points(layers: int, roulette: bool, parallax: bool) -> str:
    """neumat_eval / neumat_eval_lod: decode the latent filtered at uv (`spatial_entry_points`), or with
    `parallax` at the offset module's uv' = nm_parallax(wo, uv, footprint or lod) (`_parallax`); with `roulette`
    the two-level expectation (`_two_level`; a renderer that wants one decode per hit draws the level itself with
    nm_spatial_footprint_level)."""
    if not roulette and not parallax:
        return spatial_entry_points(layers)
    out = ""
    for signature, where, read in (("vec3 neumat_eval(vec3 wi, vec3 wo, vec2 uv, mat2 footprint)", "footprint",
                                    "nm_spatial_footprint"),
                                   ("vec3 neumat_eval_lod(vec3 wi, vec3 wo, vec2 uv, float lod)", "lod",
                                    "nm_spatial_lod")):
        shift = f"    uv = nm_parallax(wo, uv, {where});\n" if parallax else ""
        decode = _two_level(layers, f"{read}_level", f"uv, {where}", "nm_decode") if roulette else f"""\
    vec4 z[{layers}];
    {read}(uv, {where}, z);
    return nm_decode(wi, wo, z);"""
        out += f"""
{signature} {{
    if (wi.z <= 0.0 || wo.z <= 0.0) return vec3(0.0);
{shift}{decode}
}}
"""
    return out


def _parallax(model: NeuMIP) -> tuple[str, dict[str, np.ndarray]]:
    """GLSL and texture of NeuMIP's neural offset module (`NeuMIP.offset_uv`): the offset pyramid
    (`pyramid_reader` named "offset", same atlas layout as the spatial one), the offset MLP (SiLU, linear output)
    of its latent and wo, and `vec2 nm_parallax(vec3 wo, vec2 uv, mat2 footprint)` / `(..., float lod)`:
    uv' = uv + h wo.xy / max(wo.z, offset_min_cos), h = MLP_o(z_o, wo) / spatial_size (uv units), z_o the
    offset latent filtered at the footprint (or lod) at uv."""
    cfg = model.cfg
    with torch.no_grad():
        src, textures = pyramid_reader(model.offset_texture.levels(), model.offset_texture.max_probes,
                                       name="offset")
    channels, layers = cfg.offset_channels, -(-cfg.offset_channels // 4)
    inputs = [f"zo[{i // 4}].{'xyzw'[i % 4]}" for i in range(channels)] + [f"wo.{c}" for c in "xyz"]  # [z_o, wo]
    consts, body, out = mlp_chain("NM_O", model.offset_mlp, inputs, "nm_silu")
    src += "\n".join(consts) + f"""

// the offset module's lookup point uv' of the offset latent zo at uv (neumip.NeuMIP.offset_uv)
vec2 nm_parallax_shift(vec3 wo, vec2 uv, vec4 zo[{layers}]) {{
{body}    float h = {out}[0] / {cfg.spatial_size}.0;
    return uv + h * wo.xy / max(wo.z, {cfg.offset_min_cos:.9e});
}}

vec2 nm_parallax(vec3 wo, vec2 uv, mat2 footprint) {{
    vec4 zo[{layers}];
    nm_offset_footprint(uv, footprint, zo);
    return nm_parallax_shift(wo, uv, zo);
}}

vec2 nm_parallax(vec3 wo, vec2 uv, float lod) {{
    vec4 zo[{layers}];
    nm_offset_lod(uv, lod, zo);
    return nm_parallax_shift(wo, uv, zo);
}}
"""
    return src, textures


def export_latent_mlp(model: NeuMIP) -> GLSLExport:
    """GLSL source and textures of a neumip-family model (module docstring)."""
    from neumat.methods.neural_appearance.model import NeuralAppearance
    from neumat.methods.neural_appearance.proxy_sampler import DEFENSIVE

    if not isinstance(model, NeuMIP):
        raise InputError(f"export_latent_mlp: expected a neumip-family model, got {type(model).__name__}")
    cfg = model.cfg
    if cfg.directions != "cartesian":
        raise InputError(f"export_glsl: {model.name} with {cfg.directions!r} directions has no GLSL export "
                         "(cartesian only)")
    if getattr(cfg, "sampler_lobes", "anisotropic") != "anisotropic":
        raise InputError(f"export_glsl: {model.name} with sampler_lobes={cfg.sampler_lobes!r} (an ablation) has no "
                         "GLSL export (the shader decodes the paper's 9 lobe parameters)")
    roulette = cfg.level_selection == "roulette"
    ds, zl = cfg.spatial_channels, -(-cfg.spatial_channels // 4)
    zs = "z[i / 4][i % 4]"
    src, textures = _spatial_reader(model, roulette)
    parts, consts = [_COMMON, src], []
    if cfg.offset:
        offset_src, offset_textures = _parallax(model)
        parts.append(offset_src)
        textures.update(offset_textures)
    frames = cfg.frames if model.frame is not None else 0
    decode = ""
    if frames:
        frame_consts, frame_code = shading_frames(model.frame, ds, zs)
        consts += frame_consts
        decode += frame_code
        n_dir = 3 * frames
        direction = (f"(i < {n_dir} ? di[i / 3][i % 3] : dw[(i - {n_dir}) / 3][(i - {n_dir}) % 3])")
    else:
        n_dir = 3
        direction = "(i < 3 ? wi[i] : wo[i - 3])"
    in_dim = ds + 2 * n_dir
    decode += f"    float x[{in_dim}];\n    for (int i = 0; i < {ds}; ++i) x[i] = {zs};\n"
    decode += f"    for (int i = 0; i < {2 * n_dir}; ++i) x[{ds} + i] = {direction};\n"
    mlp_consts, mlp_body, out = mlp_chain("NM_L", model.mlp, "x[i]", "nm_silu")
    consts += mlp_consts
    decode += mlp_body
    outputs = model.outputs  # log f, then log albedo for neural-appearance with Config.albedo (Sec. 6.4)
    parts.append("\n".join(consts))
    parts.append(f"""void nm_outputs(vec3 wi, vec3 wo, vec4 z[{zl}], out float o[{outputs}]) {{
{decode}    for (int i = 0; i < {outputs}; ++i) o[i] = {out}[i];
}}

vec3 nm_decode(vec3 wi, vec3 wo, vec4 z[{zl}]) {{
    float o[{outputs}];
    nm_outputs(wi, wo, z, o);
    return exp(vec3(o[0], o[1], o[2]));
}}
""")
    parts.append(_entry_points(zl, roulette, cfg.offset))
    entry = ["vec3 neumat_eval(vec3 wi, vec3 wo, vec2 uv, mat2 footprint)",
             "vec3 neumat_eval_lod(vec3 wi, vec3 wo, vec2 uv, float lod)"]
    if outputs > 3:
        albedo_body = _two_level(zl, "nm_spatial_footprint_level", "uv, footprint", "nm_decode_albedo") \
            if roulette else f"""    vec4 z[{zl}];
    nm_spatial_footprint(uv, footprint, z);
    return nm_decode_albedo(wi, wo, z);"""
        parts.append(f"""vec3 nm_decode_albedo(vec3 wi, vec3 wo, vec4 z[{zl}]) {{
    float o[{outputs}];
    nm_outputs(wi, wo, z, o);
    return exp(vec3(o[3], o[4], o[5]));
}}

vec3 neumat_albedo(vec3 wi, vec3 wo, vec2 uv, mat2 footprint) {{
    if (wi.z <= 0.0 || wo.z <= 0.0) return vec3(0.0);
{albedo_body}
}}
""")
        entry.append("vec3 neumat_albedo(vec3 wi, vec3 wo, vec2 uv, mat2 footprint)")
    if isinstance(model, NeuralAppearance):
        # the BRDF from the hit's latent (trilinear level selection: eval's latent is the sampler's)
        lobes_eval = "" if roulette else """
vec3 neumat_eval(NeumatLobes l, vec3 wo) {
    if (l.wi.z <= 0.0 || wo.z <= 0.0) return vec3(0.0);
    return nm_decode(l.wi, wo, l.z);
}
"""
        sampler_input = [f"wi.{c}" for c in "xyz"] + [f"z[{i // 4}].{'xyzw'[i % 4]}"      # [wi, z] as ProxySampler
                                                      for i in range(model.sampler.mlp.linears()[0].in_features - 3)]
        s_consts, s_body, s_out = mlp_chain("NM_S", model.sampler.mlp, sampler_input, "nm_relu")
        parts.append(_SAMPLING + "\n".join(s_consts))
        parts.append(f"""
NmLobes nm_lobes(vec3 wi, vec4 z[{zl}]) {{
{s_body}    float r[9];
    for (int i = 0; i < 9; ++i) r[i] = {s_out}[i];
    NmLobes p;
    float top = max(r[0], r[3]);
    float ed = exp(r[0] - top), es = exp(r[3] - top);
    p.wd = ed / (ed + es);
    p.mud = vec2(nm_soft_sinh(r[1]), nm_soft_sinh(r[2]));
    p.alpha = {MIN_ALPHA:.9e} + (1.0 - {MIN_ALPHA:.9e}) * (vec2(nm_soft_tanh(r[4]), nm_soft_tanh(r[5])) + 1.0) / 2.0;
    p.rho = {MAX_RHO:.9e} * nm_soft_tanh(r[6]);
    p.mus = vec2(nm_soft_sinh(r[7]), nm_soft_sinh(r[8]));
    return p;
}}

// one hit's filtered latent and sampler lobes: the sampler MLP runs once, sample / pdf / eval reuse it
struct NeumatLobes {{ vec3 wi; vec4 z[{zl}]; NmLobes p; }};

NeumatLobes neumat_lobes(vec3 wi, vec2 uv, mat2 footprint) {{
    NeumatLobes l;
    l.wi = wi;
    nm_spatial_footprint(uv, footprint, l.z);
    l.p = nm_lobes(wi, l.z);
    return l;
}}

vec3 neumat_sample(NeumatLobes l, vec2 u) {{
    bool cosine = u.x < {DEFENSIVE:.9e};
    float u0 = cosine ? u.x / {DEFENSIVE:.9e} : (u.x - {DEFENSIVE:.9e}) / {1 - DEFENSIVE:.9e};
    vec2 v = vec2(clamp(u0, 0.0, 1.0 - 1e-7), u.y);
    vec3 wo = cosine ? nm_cosine(v) : nm_proxy_sample(l.p, l.wi, v);
    return normalize(wo);
}}

float neumat_pdf(NeumatLobes l, vec3 wo) {{
    return {1 - DEFENSIVE:.9e} * nm_proxy_pdf(l.p, l.wi, wo) + {DEFENSIVE:.9e} * max(wo.z, 0.0) / {math.pi:.9e};
}}
{lobes_eval}
vec3 neumat_sample(vec3 wi, vec2 uv, mat2 footprint, vec2 u) {{
    return neumat_sample(neumat_lobes(wi, uv, footprint), u);
}}

float neumat_pdf(vec3 wi, vec3 wo, vec2 uv, mat2 footprint) {{
    return neumat_pdf(neumat_lobes(wi, uv, footprint), wo);
}}
""")
        entry += ["vec3 neumat_sample(vec3 wi, vec2 uv, mat2 footprint, vec2 u)",
                  "float neumat_pdf(vec3 wi, vec3 wo, vec2 uv, mat2 footprint)",
                  "NeumatLobes neumat_lobes(vec3 wi, vec2 uv, mat2 footprint)",
                  "vec3 neumat_sample(NeumatLobes l, vec2 u)", "float neumat_pdf(NeumatLobes l, vec3 wo)"]
        if not roulette:
            entry.append("vec3 neumat_eval(NeumatLobes l, vec3 wo)")
    header = f"// neumat GLSL export of a '{model.name}' model; see neumat.methods.latent_mlp.glsl.\n"
    return GLSLExport(header + "\n".join(parts), textures, True, entry)
