"""GLSL export of SparseBTF (Kavoosi et al. 2023, Sec. 3.4: the sparse coefficients, their index tuples, the
membership vector and the dictionary ensemble uploaded as textures, one BTF element reconstructed per query).

`export_sparse_btf(model)` computes what `SparseBTF.eval` computes with `angular = "coefficient"`; entry
points `neumat_eval` / `neumat_eval_lod`; textures `sbtf_codes`, `sbtf_points`, `sbtf_dict_s`, `sbtf_dict_a`,
`sbtf_stats`.

Details: docs/formats/glsl.md, section `neumat.methods.sparse_btf.glsl`.
"""
from __future__ import annotations

import numpy as np
import torch

from neumat.core.errors import InputError
from neumat.methods.sparse_btf.model import SparseBTF
from neumat.methods.sparse_btf.dictionary import YUV_TO_RGB
from neumat.export.glsl_common import GLSLExport

#: the largest texture side the export relies on (OpenGL 3.3 guarantees 1024; desktop GPUs give 16384)
MAX_SIDE = 16384
#: data points per row of sbtf_points
POINTS_WIDTH = 1024
ENTRY_POINTS = ["vec3 neumat_eval(vec3 wi, vec3 wo, vec2 uv)",
                "vec3 neumat_eval(vec3 wi, vec3 wo, vec2 uv, mat2 footprint)",
                "vec3 neumat_eval_lod(vec3 wi, vec3 wo, vec2 uv, float lod)"]


def _vec3s(name: str, dirs: torch.Tensor) -> str:
    body = ", ".join(f"vec3({x:.9e}, {y:.9e}, {z:.9e})" for x, y, z in dirs.double().tolist())
    return f"const vec3 {name}[{len(dirs)}] = vec3[]({body});"


def _rgba(*channels: torch.Tensor) -> np.ndarray:
    """Stack up to four (layers, H, W) tensors into float32 (layers, H, W, 4), the rest zero."""
    out = np.zeros((*channels[0].shape, 4), np.float32)
    for i, ch in enumerate(channels):
        out[..., i] = ch.detach().float().cpu().numpy()
    return out


def _textures(model: SparseBTF) -> dict[str, np.ndarray]:
    c = model.cfg
    p, k, n_points = c.patch, c.num_dictionaries, model.counts.shape[1]
    t = model.values.shape[2]
    side = max(c.n_light, c.n_view)
    if n_points > MAX_SIDE or t > MAX_SIDE or side > MAX_SIDE:
        raise InputError(f"export_glsl: this SparseBTF needs textures of {n_points} x {t} and {side} x {side} "
                         f"texels; the export supports sides up to {MAX_SIDE}")
    idx = model.index.long()
    codes = _rgba(model.values, (idx[..., 0] * p + idx[..., 1]).float(), idx[..., 2].float(), idx[..., 3].float())
    rows = -(-n_points // POINTS_WIDTH)
    width = min(n_points, POINTS_WIDTH)
    pad = rows * width - n_points
    membership = torch.nn.functional.pad(model.membership.float(), (0, pad)).reshape(3, rows, width)
    counts = torch.nn.functional.pad(model.counts.float(), (0, pad)).reshape(3, rows, width)
    d3 = torch.zeros(3 * k, side, side)
    d4 = torch.zeros(3 * k, side, side)
    d3[:, :c.n_light, :c.n_light] = model.dict_3.reshape(3 * k, c.n_light, c.n_light)
    d4[:, :c.n_view, :c.n_view] = model.dict_4.reshape(3 * k, c.n_view, c.n_view)
    stats = torch.stack([model.mean, model.std])                                  # (2, L, V, 3)
    return {
        "sbtf_codes": codes,
        "sbtf_points": _rgba(membership, counts),
        "sbtf_dict_s": _rgba(model.dict_1.reshape(3 * k, p, p), model.dict_2.reshape(3 * k, p, p)),
        "sbtf_dict_a": _rgba(d3, d4),
        "sbtf_stats": _rgba(stats[..., 0], stats[..., 1], stats[..., 2]),
    }


_SOURCE = """// SparseBTF ({describe}), exported by neumat
const int SB_H = {h}, SB_W = {w}, SB_P = {p}, SB_PW = {pw}, SB_K = {k}, SB_L = {l}, SB_V = {v};
const int SB_NB = {nb}, SB_POINTS_W = {points_w};
const float SB_EPS = {eps:.9e};
// YUV -> RGB, one row per output channel (dot products, not a mat3: no column-major convention to get wrong)
const vec3 SB_TO_R = vec3({to_r}), SB_TO_G = vec3({to_g}), SB_TO_B = vec3({to_b});
{light_dirs}
{view_dirs}
uniform sampler2DArray sbtf_codes;
uniform sampler2DArray sbtf_points;
uniform sampler2DArray sbtf_dict_s;
uniform sampler2DArray sbtf_dict_a;
uniform sampler2DArray sbtf_stats;

// i (a whole number, any sign) modulo n, in [0, n); GLSL's % is undefined for negative operands
int sb_wrap(float i, int n) {{ int r = int(i - float(n) * floor(i / float(n))); return r >= n ? r - n : r; }}

vec3 sb_dir(bool light, int i) {{ return light ? SB_LIGHT[i] : SB_VIEW[i]; }}

// the SB_NB bins nearest to w (largest dot product first) and their inverse-angular-distance weights
void sb_nearest(vec3 w, bool light, out int idx[SB_NB], out float wt[SB_NB]) {{
    float best[SB_NB];
    for (int i = 0; i < SB_NB; ++i) {{ best[i] = -3.0; idx[i] = 0; }}
    int n = light ? SB_L : SB_V;
    for (int d = 0; d < n; ++d) {{
        float s = dot(w, sb_dir(light, d));
        if (s > best[SB_NB - 1]) {{
            int j = SB_NB - 1;
            while (j > 0 && s > best[j - 1]) {{ best[j] = best[j - 1]; idx[j] = idx[j - 1]; --j; }}
            best[j] = s; idx[j] = d;
        }}
    }}
    bool exact = false;
    float angle[SB_NB];
    for (int i = 0; i < SB_NB; ++i) {{
        vec3 t = sb_dir(light, idx[i]);
        angle[i] = atan(length(cross(w, t)), dot(w, t));
        exact = exact || angle[i] <= 1e-7;
    }}
    float total = 0.0;
    for (int i = 0; i < SB_NB; ++i) {{
        wt[i] = exact ? (angle[i] <= 1e-7 ? 1.0 : 0.0) : 1.0 / max(angle[i], 1e-7);
        total += wt[i];
    }}
    for (int i = 0; i < SB_NB; ++i) wt[i] /= total;
}}

vec3 neumat_eval(vec3 wi, vec3 wo, vec2 uv) {{
    if (wi.z <= 0.0 || wo.z <= 0.0) return vec3(0.0);
    int li[SB_NB], vi[SB_NB];
    float lw[SB_NB], vw[SB_NB];
    sb_nearest(wi, true, li, lw);
    sb_nearest(wo, false, vi, vw);
    float x = uv.x * float(SB_W) - 0.5, y = (1.0 - uv.y) * float(SB_H) - 0.5;
    float x0 = floor(x), y0 = floor(y), fx = x - x0, fy = y - y0;
    int row[2] = int[](sb_wrap(y0, SB_H), sb_wrap(y0 + 1.0, SB_H));
    int col[2] = int[](sb_wrap(x0, SB_W), sb_wrap(x0 + 1.0, SB_W));
    float wy[2] = float[](1.0 - fy, fy), wx[2] = float[](1.0 - fx, fx);
    // the 4 taps are rows x cols; both rows (cols) lie in one patch row (col) unless they straddle a patch
    // edge, so the taps fall in 1, 2 or 4 data points, each visited once with the separable spatial factor
    // (sum over its rows of wy U1[x1, l1]) x (sum over its cols of wx U2[x2, l2])
    bool one_r = row[0] / SB_P == row[1] / SB_P, one_c = col[0] / SB_P == col[1] / SB_P;
    vec3 z = vec3(0.0);
    for (int a = 0; a < (one_r ? 1 : 2); ++a)
        for (int b = 0; b < (one_c ? 1 : 2); ++b) {{
            int point = (row[a] / SB_P) * SB_PW + col[b] / SB_P;
            int r0 = row[a] % SB_P, r1 = row[one_r ? 1 : a] % SB_P, c0 = col[b] % SB_P, c1 = col[one_c ? 1 : b] % SB_P;
            float wr0 = one_r ? wy[0] : wy[a], wr1 = one_r ? wy[1] : 0.0;
            float wc0 = one_c ? wx[0] : wx[b], wc1 = one_c ? wx[1] : 0.0;
            for (int c = 0; c < 3; ++c) {{
                vec4 info = texelFetch(sbtf_points, ivec3(point % SB_POINTS_W, point / SB_POINTS_W, c), 0);
                int layer = c * SB_K + int(info.x), count = int(info.y);
                float acc = 0.0;
                for (int t = 0; t < count; ++t) {{
                    vec4 code = texelFetch(sbtf_codes, ivec3(t, point, c), 0);
                    int l1 = int(code.y) / SB_P, l2 = int(code.y) % SB_P, l3 = int(code.z), l4 = int(code.w);
                    float u1 = wr0 * texelFetch(sbtf_dict_s, ivec3(l1, r0, layer), 0).x
                             + wr1 * texelFetch(sbtf_dict_s, ivec3(l1, r1, layer), 0).x;
                    float u2 = wc0 * texelFetch(sbtf_dict_s, ivec3(l2, c0, layer), 0).y
                             + wc1 * texelFetch(sbtf_dict_s, ivec3(l2, c1, layer), 0).y;
                    float u3 = 0.0, u4 = 0.0;
                    for (int i = 0; i < SB_NB; ++i) u3 += lw[i] * texelFetch(sbtf_dict_a, ivec3(l3, li[i], layer), 0).x;
                    for (int j = 0; j < SB_NB; ++j) u4 += vw[j] * texelFetch(sbtf_dict_a, ivec3(l4, vi[j], layer), 0).y;
                    acc += code.x * u1 * u2 * u3 * u4;
                }}
                z[c] += acc;
            }}
        }}
    vec3 mean = vec3(0.0), std_ = vec3(0.0);
    for (int a = 0; a < SB_NB; ++a)
        for (int b = 0; b < SB_NB; ++b) {{
            float wab = lw[a] * vw[b];
            mean += wab * texelFetch(sbtf_stats, ivec3(vi[b], li[a], 0), 0).xyz;
            std_ += wab * texelFetch(sbtf_stats, ivec3(vi[b], li[a], 1), 0).xyz;
        }}
    vec3 yuv = z * std_ + mean;
    return max(exp(vec3(dot(SB_TO_R, yuv), dot(SB_TO_G, yuv), dot(SB_TO_B, yuv))) - SB_EPS, vec3(0.0));
}}

vec3 neumat_eval(vec3 wi, vec3 wo, vec2 uv, mat2 footprint) {{ return neumat_eval(wi, wo, uv); }}
vec3 neumat_eval_lod(vec3 wi, vec3 wo, vec2 uv, float lod) {{ return neumat_eval(wi, wo, uv); }}
"""


def export_sparse_btf(model: SparseBTF) -> GLSLExport:
    """GLSL source and textures computing `model.eval` with coefficient-space angular interpolation (module
    docstring). A model set to `angular = "value"` is exported with the coefficient-space path (the paper's
    runtime); the two agree on table entries and differ slightly between bins."""
    c = model.cfg
    if not torch.isfinite(model.values).all() or not torch.isfinite(model.mean).all() \
            or not torch.isfinite(model.std).all():
        raise InputError("export_glsl: this SparseBTF has non-finite coefficients or statistics")
    nb = min(c.neighbours, c.n_light, c.n_view)
    if nb != min(c.neighbours, c.n_light) or nb != min(c.neighbours, c.n_view):
        raise InputError(f"export_glsl: {c.neighbours} neighbours with {c.n_light} light and {c.n_view} view "
                         "directions: the shader needs the same neighbour count for both")
    to_r, to_g, to_b = (", ".join(f"{v:.9e}" for v in row.tolist()) for row in YUV_TO_RGB)
    source = _SOURCE.format(
        describe=model.describe(), h=c.height, w=c.width, p=c.patch, pw=c.width // c.patch,
        k=c.num_dictionaries, l=c.n_light, v=c.n_view, nb=nb, points_w=min(model.counts.shape[1], POINTS_WIDTH),
        eps=c.log_eps, to_r=to_r, to_g=to_g, to_b=to_b, light_dirs=_vec3s("SB_LIGHT", model.light_dirs),
        view_dirs=_vec3s("SB_VIEW", model.view_dirs))
    textures = _textures(model)  # float32 at every precision: coefficients share texels with their indices
    return GLSLExport(source, textures, spatially_varying=True, entry=ENTRY_POINTS, exact=tuple(textures))
