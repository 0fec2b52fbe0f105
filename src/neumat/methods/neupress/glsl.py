"""GLSL export of NeuPreSS (TG et al.): the appearance module and its light sampler as shader functions, for
a renderer that lights a translucent object by a distant environment (Eq. 5).

Entry points: `neumat_translucent`, `neumat_sigma`, `neumat_sample_incident`, `neumat_incident_pdf`,
`neumat_translucent_shade`, `neumat_rough_dielectric_reflection`; the networks' weights lie in the RGBA32F
texture `neumat_weights`, the environment in `neumat_env`.

Details: docs/formats/glsl.md, section `neumat.methods.neupress.glsl`.
"""
from __future__ import annotations

import math

import numpy as np
import torch

from neumat.core.errors import InputError
from neumat.methods.neupress.model import SIGMA_MAX, SIGMA_MIN, NeuPreSS
from neumat.export.glsl_common import _COMMON, GLSLExport

#: texels per row of the weight texture
WIDTH = 1024

_LOBE = """
float nm_expm1(float x) { return abs(x) < 1e-3 ? x * (1.0 + x * (0.5 + x / 6.0)) : exp(x) - 1.0; }
float nm_log1p(float x) { return abs(x) < 1e-3 ? x * (1.0 - x * (0.5 - x / 3.0)) : log(1.0 + x); }

vec4 nm_w(int k) { return texelFetch(neumat_weights, ivec3(k % @WIDTH@, k / @WIDTH@, 0), 0); }

// 1, the texture's layer count: a loop bound the compiler cannot know keeps it from unrolling the matrix
// products completely (Mesa then spends minutes compiling the paper-size networks)
int nm_one() { return textureSize(neumat_weights, 0).z; }

// (theta / pi, phi / 2 pi) of neumat.core.coords.dir_to_spherical, or the vector itself
void nm_direction(vec3 w, inout vec4 v[3], int at) {
@DIRECTION@
}

// azimuthal-equidistant Gaussian lobe (neumat.warp.azimuthal_gaussian), truncated at pi
float nm_lobe_pdf(vec3 w, vec3 axis, float sigma) {
    vec3 dv = w - axis, sv = w + axis;
    float d2 = max(dot(dv, dv), 1.2e-38), s2 = max(dot(sv, sv), 1.2e-38);
    float d = sqrt(d2), s = sqrt(s2);
    float theta = 2.0 * atan(d, s);
    float ratio = theta * (d2 + s2) / (2.0 * d * s);
    float c = -nm_expm1(-0.5 * (3.141592654 / sigma) * (3.141592654 / sigma));
    return exp(-0.5 * (theta / sigma) * (theta / sigma)) / (6.283185307 * sigma * sigma * c) * ratio;
}

vec3 nm_lobe_sample(vec2 u, vec3 axis, float sigma) {
    float c = nm_expm1(-0.5 * (3.141592654 / sigma) * (3.141592654 / sigma));
    float arg = max(u.x * c, -(1.0 - 5.96e-8));
    float r = min(sigma * sqrt(max(-2.0 * nm_log1p(arg), 1.2e-38)), 3.141592654);
    float phi = 6.283185307 * u.y;
    vec3 t, b;
    nm_basis(axis, t, b);
    return sin(r) * cos(phi) * t + sin(r) * sin(phi) * b + cos(r) * axis;
}
"""


def export_neupress(model: NeuPreSS) -> GLSLExport:
    """GLSL source and the weight texture of a NeuPreSS model (module docstring)."""
    if not isinstance(model, NeuPreSS):
        raise InputError(f"export_neupress: expected a NeuPreSS model, got {type(model).__name__}")
    packer = _Packer()
    cfg = model.cfg
    spherical = cfg.direction_encoding == "spherical"
    d = 2 if spherical else 3
    consts = [f"const vec3 NM_BOX_MIN = {_vec3(model.box_min)};",
              f"const vec3 NM_BOX_SIZE = {_vec3(model.box_max - model.box_min)};"]

    a_feat = packer.fourier("NM_AG", model.appearance_features)
    a_net = packer.skip_mlp("NM_A", model.appearance)
    s_feat = packer.fourier("NM_SG", model.sampler_features)
    s_net = packer.sequential("NM_S", [m for m in model.sampler if isinstance(m, torch.nn.Linear)])
    consts += packer.offsets
    f4 = -(-2 * cfg.features // 4)  # vec4s of the feature array
    direction = ("    float theta = atan(length(w.xy), w.z);  // = acos(w.z); llvmpipe's acos is far less precise\n"
                 "    float phi = mod(atan(w.y, w.x), 6.283185307);\n"
                 "    v[at / 4][at % 4] = theta / 3.141592654; v[(at + 1) / 4][(at + 1) % 4] = phi / 6.283185307;"
                 if spherical else
                 "    for (int i = 0; i < 3; ++i) v[(at + i) / 4][(at + i) % 4] = w[i];")
    source = "\n".join([
        "// neumat GLSL export of a 'neupress' model; see neumat.methods.neupress.glsl.\n"
        "uniform sampler2DArray neumat_weights;\n", _COMMON, "\n".join(consts),
        _LOBE.replace("@WIDTH@", str(WIDTH)).replace("@DIRECTION@", direction), _MATVEC, f"""
vec3 neumat_translucent(vec3 wi, vec3 x, vec3 wo) {{
    vec4 v[3] = vec4[3](vec4(0.0), vec4(0.0), vec4(0.0));
    nm_direction(wi, v, 0);
    nm_direction(wo, v, {d});
    vec3 p = (x - NM_BOX_MIN) / NM_BOX_SIZE;
    for (int i = 0; i < 3; ++i) v[({2 * d} + i) / 4][({2 * d} + i) % 4] = p[i];
    vec4 f[{f4}];
{a_feat}{a_net}    return max(h_out[0].xyz, vec3(0.0));
}}

float neumat_sigma(vec3 x, vec3 wo) {{
    vec4 v[3] = vec4[3](vec4((x - NM_BOX_MIN) / NM_BOX_SIZE, 0.0), vec4(0.0), vec4(0.0));
    nm_direction(wo, v, 3);
    vec4 f[{f4}];
{s_feat}{s_net}    return exp(clamp(h_out[0].x, {math.log(SIGMA_MIN):.9e}, {math.log(SIGMA_MAX):.9e}));
}}

vec3 neumat_sample_incident(vec3 x, vec3 wo, vec3 n, vec2 u) {{
    return normalize(nm_lobe_sample(u, n, neumat_sigma(x, wo)));
}}

float neumat_incident_pdf(vec3 wi, vec3 x, vec3 wo, vec3 n) {{
    return nm_lobe_pdf(wi, n, neumat_sigma(x, wo));
}}
""", _SHADE])
    entry = ["vec3 neumat_translucent(vec3 wi, vec3 x, vec3 wo)", "float neumat_sigma(vec3 x, vec3 wo)",
             "vec3 neumat_sample_incident(vec3 x, vec3 wo, vec3 n, vec2 u)",
             "float neumat_incident_pdf(vec3 wi, vec3 x, vec3 wo, vec3 n)",
             "vec3 neumat_translucent_shade(vec3 x, vec3 n, vec3 wo, float alpha, float ior, int samples)",
             "float neumat_rough_dielectric_reflection(vec3 n, vec3 wo, vec3 wi, float alpha, float ior)"]
    # float32 at every precision: the texture holds the Fourier matrices too, whose phases reach ~400 rad
    return GLSLExport(source, {"neumat_weights": packer.texture()}, spatially_varying=False, entry=entry,
                      exact=("neumat_weights",))


_SHADE = """
// ---- shading a fragment (neumat_env: equirectangular radiance bound by the renderer)
uniform sampler2DArray neumat_env;

vec3 nm_env(vec3 d) {
    ivec3 size = textureSize(neumat_env, 0);
    float u = mod(atan(d.x, -d.z) / 6.283185307, 1.0);
    float v = atan(length(d.xz), d.y) / 3.141592654;
    int i = clamp(int(v * float(size.y)), 0, size.y - 1);
    int j = clamp(int(u * float(size.x)), 0, size.x - 1);
    return texelFetch(neumat_env, ivec3(j, i, 0), 0).rgb;
}

vec2 nm_hammersley(int k, int count) {
    uint b = uint(k);
    b = (b << 16u) | (b >> 16u);
    b = ((b & 0x55555555u) << 1u) | ((b & 0xAAAAAAAAu) >> 1u);
    b = ((b & 0x33333333u) << 2u) | ((b & 0xCCCCCCCCu) >> 2u);
    b = ((b & 0x0F0F0F0Fu) << 4u) | ((b & 0xF0F0F0F0u) >> 4u);
    b = ((b & 0x00FF00FFu) << 8u) | ((b & 0xFF00FF00u) >> 8u);
    return vec2((float(k) + 0.5) / float(count), float(b >> 8u) * 5.9604645e-08);
}

float nm_fresnel(float cos_i, float eta) {
    float sin2_t = (1.0 - cos_i * cos_i) / (eta * eta);
    if (sin2_t >= 1.0) return 1.0;
    float cos_t = sqrt(1.0 - sin2_t);
    float rs = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);
    float rp = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
    return 0.5 * (rs * rs + rp * rp);
}

float nm_ggx_d(float cos_h, float alpha) {
    float a2 = alpha * alpha, t = cos_h * cos_h * (a2 - 1.0) + 1.0;
    return a2 / (3.141592654 * t * t);
}

float nm_ggx_g1(vec3 v, vec3 h, vec3 n, float alpha) {
    float c = dot(v, n);
    if (dot(v, h) * c <= 0.0) return 0.0;
    float tan2 = max(1.0 - c * c, 0.0) / (c * c);
    return 2.0 / (1.0 + sqrt(1.0 + alpha * alpha * tan2));
}

float neumat_rough_dielectric_reflection(vec3 n, vec3 wo, vec3 wi, float alpha, float ior) {
    float co = dot(n, wo), ci = dot(n, wi);
    if (co <= 0.0 || ci <= 0.0) return 0.0;
    vec3 h = normalize(wo + wi);
    return nm_fresnel(dot(wo, h), ior) * nm_ggx_d(dot(n, h), alpha) * nm_ggx_g1(wo, h, n, alpha)
        * nm_ggx_g1(wi, h, n, alpha) / (4.0 * co);
}

vec3 neumat_translucent_shade(vec3 x, vec3 n, vec3 wo, float alpha, float ior, int samples) {
    float sigma = neumat_sigma(x, wo);
    float co = dot(n, wo);
    vec3 t, b;
    nm_basis(n, t, b);
    vec3 sum = vec3(0.0);
    for (int k = 0; k < samples; ++k) {
        vec2 u = nm_hammersley(k, samples);
        // surface: a GGX normal h (density D(h) cos theta_h), the mirror direction, weight F G (wo.h) / (co cos_h)
        float cos2 = 1.0 / (1.0 + alpha * alpha * u.x / (1.0 - u.x));
        float cos_h = sqrt(cos2), sin_h = sqrt(max(1.0 - cos2, 0.0)), phi = 6.283185307 * u.y;
        vec3 h = sin_h * cos(phi) * t + sin_h * sin(phi) * b + cos_h * n;
        float oh = dot(wo, h);
        vec3 wr = 2.0 * oh * h - wo;
        if (co > 0.0 && dot(n, wr) > 0.0 && oh > 0.0)
            sum += nm_fresnel(oh, ior) * nm_ggx_g1(wo, h, n, alpha) * nm_ggx_g1(wr, h, n, alpha) * oh
                   / (co * cos_h) * nm_env(wr);
        // subsurface: the model's lobe
        vec3 wi = normalize(nm_lobe_sample(u, n, sigma));
        float pdf = nm_lobe_pdf(wi, n, sigma);
        if (pdf > 0.0) sum += neumat_translucent(wi, x, wo) * nm_env(wi) / pdf;
    }
    return sum / float(samples);
}
"""

# Y = B + W X for vec4 arrays X (IN4 long) and Y (OUT4 long); W has 4 OUT4 rows of IN4 texels (zero-padded), the
# bias OUT4 texels
_MATVEC = """
#define NM_MATVEC(W, B, IN4, OUT4, X, Y) \\
    for (int o = 0; o < OUT4 * nm_one(); ++o) { \\
        vec4 acc = nm_w(B + o); \\
        for (int j = 0; j < IN4 * nm_one(); ++j) { \\
            vec4 xj = X[j]; \\
            acc += vec4(dot(nm_w(W + (4 * o) * IN4 + j), xj), dot(nm_w(W + (4 * o + 1) * IN4 + j), xj), \\
                        dot(nm_w(W + (4 * o + 2) * IN4 + j), xj), dot(nm_w(W + (4 * o + 3) * IN4 + j), xj)); \\
        } \\
        Y[o] = acc; \\
    }
"""


class _Packer:
    """Collects matrices into the weight texture and names their offsets (in texels) as GLSL constants."""

    def __init__(self) -> None:
        self.chunks: list[np.ndarray] = []
        self.size = 0
        self.offsets: list[str] = []

    def add(self, name: str, matrix: torch.Tensor) -> tuple[str, int]:
        """Store `matrix` (out, in) (or a vector, as a row) zero-padded to a multiple of 4 rows (matrices only) of
        ceil(in / 4) texels; returns its constant's name and the texels per row."""
        m = matrix.detach().double().cpu()
        rows = -(-m.shape[0] // 4) * 4 if m.dim() == 2 else 1
        m = m.reshape(1, -1) if m.dim() == 1 else m
        if not torch.isfinite(m).all():
            raise InputError(f"export_neupress: parameter {name} has non-finite values; the model cannot be exported")
        in4 = -(-m.shape[1] // 4)
        padded = torch.zeros(rows, in4 * 4, dtype=torch.float64)
        padded[:m.shape[0], :m.shape[1]] = m
        self.chunks.append(padded.reshape(-1, 4).float().numpy())
        self.offsets.append(f"const int {name} = {self.size};")
        self.size += self.chunks[-1].shape[0]
        return name, in4

    def linear(self, name: str, layer: torch.nn.Linear, source: str, target: str, relu: bool,
               declare: bool = True) -> str:
        """Statements computing the vec4 array `target` = layer(`source`), ReLU if `relu` (padding stays 0)."""
        w, in4 = self.add(f"{name}_W", layer.weight)
        b, out4 = self.add(f"{name}_B", layer.bias)
        code = f"    vec4 {target}[{out4}];\n" if declare else ""
        code += f"    NM_MATVEC({w}, {b}, {in4}, {out4}, {source}, {target})\n"
        if relu:
            code += f"    for (int o = 0; o < {out4}; ++o) {target}[o] = max({target}[o], vec4(0.0));\n"
        return code

    def fourier(self, name: str, features) -> str:
        """Statements filling the vec4 array f with [cos, sin](2 pi G v) from vec4 v[3] (padding 0)."""
        g, in4 = self.add(name, features.G)
        n = features.G.shape[0]
        return (f"    for (int k = 0; k < {-(-2 * n // 4)}; ++k) f[k] = vec4(0.0);\n"
                f"    for (int k = 0; k < {n} * nm_one(); ++k) {{\n"
                f"        float a = 0.0;\n"
                f"        for (int j = 0; j < {in4}; ++j) a += dot(nm_w({g} + k * {in4} + j), v[j]);\n"
                f"        a = 6.283185307 * fract(a);  // cycles reduced first: GPU sin / cos lose precision far out\n"
                f"        f[k / 4][k % 4] = cos(a);\n"
                f"        f[({n} + k) / 4][({n} + k) % 4] = sin(a);\n"
                f"    }}\n")

    def skip_mlp(self, name: str, net) -> str:
        """Statements of `neumat.nn.skip_mlp.SkipMLP` (with or without skips) on f, ending in the vec4 array
        h_out."""
        code = self.linear(f"{name}0", net.first, "f", "h", relu=True)
        width4 = -(-net.width // 4)
        code += f"    vec4 t[{width4}];\n    vec4 t2[{width4}];\n"
        hidden = list(net.hidden)
        for k in range(len(hidden) // 2):
            code += self.linear(f"{name}{2 * k + 1}", hidden[2 * k], "h", "t", relu=True, declare=False)
            code += self.linear(f"{name}{2 * k + 2}", hidden[2 * k + 1], "t", "t2", relu=False, declare=False)
            skip = "h[o] + " if net.skips else ""
            code += f"    for (int o = 0; o < {width4}; ++o) h[o] = max({skip}t2[o], vec4(0.0));\n"
        if len(hidden) % 2:
            code += self.linear(f"{name}{len(hidden)}", hidden[-1], "h", "t", relu=True, declare=False)
            code += f"    for (int o = 0; o < {width4}; ++o) h[o] = t[o];\n"
        return code + self.linear(f"{name}_out", net.out, "h", "h_out", relu=False)

    def sequential(self, name: str, layers: list[torch.nn.Linear]) -> str:
        """Statements of Linear-ReLU-...-Linear on f, ending in the vec4 array h_out."""
        code, source = "", "f"
        for i, layer in enumerate(layers):
            last = i == len(layers) - 1
            target = "h_out" if last else f"s{i}"
            code += self.linear(f"{name}{i}", layer, source, target, relu=not last)
            source = target
        return code

    def texture(self) -> np.ndarray:
        """The weight texture (1, H, WIDTH, 4) float32."""
        flat = np.concatenate(self.chunks, 0)
        rows = -(-flat.shape[0] // WIDTH)
        out = np.zeros((rows * WIDTH, 4), np.float32)
        out[:flat.shape[0]] = flat
        return out.reshape(1, rows, WIDTH, 4)


def _vec3(t: torch.Tensor) -> str:
    return "vec3(" + ", ".join(f"{float(v):.9e}" for v in t.detach().cpu()) + ")"
