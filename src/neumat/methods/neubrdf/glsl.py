"""GLSL export of NeuBRDF (Dou, Zheng et al. 2024): the runtime the paper deploys in Falcor, as a shader.

`export_neubrdf(model)` computes what `model.eval` computes. Uniform corner weights (the runtime form): the
runtime's per-pixel first-layer table (`nbrdf_first`, two rows per evaluation, one vec4 texel per 4
pre-activations) and the rest of the MLP; inverse-distance weights: analytic HEALPix corners, codebook, first
layer. The MLP is unrolled in vec4 groups (`neumat.export.glsl_common.mlp_vec4`), then exp. Entry points
`neumat_eval(wi, wo[, uv[, footprint]])` and `neumat_eval_lod`; tables are RGBA32F (RGBA16F for the codebook /
features of an fp16 export) `sampler2DArray`s (`nbrdf_first`, or `nbrdf_index`, `nbrdf_features`,
`nbrdf_levels`, `nbrdf_vertices`; `export_glsl` makes them images under GLSL 4.20, `read_as_images`).

Details: docs/formats/glsl.md, section `neumat.methods.neubrdf.glsl`.
"""
from __future__ import annotations

import numpy as np
import torch

from neumat.core.errors import InputError
from neumat.methods.neubrdf.model import DIRECTION_INPUTS, NeuBRDF
from neumat.models.half_precision import half_rounded
from neumat.nn import healpix as hpx
from neumat.nn.codebook import VQFeatures
from neumat.export.glsl_common import _COMMON, GLSLExport, mlp_vec4, pyramid_reader, vec4_components

TABLE_WIDTH = 1024
"""Texels per row of the lookup tables."""

ACTIVATIONS = {
    "relu": "float nm_act(float x) { return max(x, 0.0); }",
    "leaky_relu": "float nm_act(float x) { return x >= 0.0 ? x : 0.01 * x; }",
    "silu": "float nm_act(float x) { return nm_silu(x); }",
    "tanh": "float nm_act(float x) { return tanh(x); }",
    "sigmoid": "float nm_act(float x) { return 1.0 / (1.0 + exp(-x)); }",
    "softplus": "float nm_act(float x) { return nm_softplus(x); }",
}
"""GLSL of the MLP's hidden activations (`neumat.nn.mlp.ACTIVATIONS`; leaky ReLU with torch's slope 0.01)."""

_HEALPIX = """
const int NM_JRLL[12] = int[](2, 2, 2, 2, 3, 3, 3, 3, 4, 4, 4, 4);
const int NM_JPLL[12] = int[](1, 3, 5, 7, 0, 2, 4, 6, 1, 3, 5, 7);

// i mod m in [0, m) for any sign of i
int nm_mod(int i, int m) { int r = i - (i / m) * m; return r < 0 ? r + m : r; }

// floor(sqrt(x)), exact for 0 <= x < 2^31
int nm_isqrt(int x) {
    int r = int(sqrt(float(x)));
    if (r * r > x) r -= 1;
    if (r * r > x) r -= 1;
    if ((r + 1) * (r + 1) <= x) r += 1;
    if ((r + 1) * (r + 1) <= x) r += 1;
    return r;
}

// ring pixel of a unit vector (neumat.nn.healpix.vec2pix_xyz, float32 as there)
int nm_vec2pix(vec3 v) {
    const int n = NM_NSIDE;
    float tt = atan(v.y, v.x) * 6.366197723675814e-01;
    if (tt < 0.0) tt += 4.0;
    if (tt >= 4.0) tt = 0.0;
    float za = abs(v.z);
    if (za <= 2.0 / 3.0) {
        float temp1 = tt * float(n) + 0.5 * float(n), temp2 = v.z * (0.75 * float(n));
        int jp = int(temp1 - temp2), jm = int(temp1 + temp2);
        int ir = jp - jm + n + 1;
        int kshift = 1 - (ir & 1);
        int t = jp + jm + kshift + 1 - n;
        int ip = nm_mod(((t + 8 * n) >> 1) - 4 * n, 4 * n);
        return ip + (ir - 1) * 4 * n + 2 * n * (n - 1);
    }
    float tp = fract(tt);
    float tmp = sqrt(v.x * v.x + v.y * v.y) * float(n) / sqrt((za + 1.0) * (1.0 / 3.0));
    int jp = int(tp * tmp), jm = int((1.0 - tp) * tmp);
    int ir = jp + jm + 1;
    int ip = min(int(tt * float(ir)), 4 * ir - 1);
    return v.z > 0.0 ? 2 * ir * (ir - 1) + ip : 12 * n * n - 2 * ir * (ir + 1) + ip;
}

// face coordinates (ix, iy, face) of a ring pixel (healpy pix2xyf)
void nm_ring2xyf(int pix, out int ix, out int iy, out int face) {
    const int n = NM_NSIDE;
    int ncap = 2 * n * (n - 1), npix = 12 * n * n;
    int iring, iphi, nr, kshift = 0;
    if (pix < ncap) {
        iring = (1 + nm_isqrt(1 + 2 * pix)) >> 1;
        iphi = pix + 1 - 2 * iring * (iring - 1);
        nr = iring;
        face = (iphi - 1) / iring;
    } else if (pix < npix - ncap) {
        int tmp = (pix - ncap) / (4 * n);
        iring = tmp + n;
        iphi = pix - ncap - tmp * 4 * n + 1;
        kshift = (iring + n) & 1;
        nr = n;
        int ifm = (iphi - ((tmp + 1) >> 1) + n - 1) / n, ifp = (iphi - ((2 * n + 1 - tmp) >> 1) + n - 1) / n;
        face = ifp == ifm ? (ifp | 4) : (ifp < ifm ? ifp : ifm + 8);
    } else {
        int ips = npix - pix;
        int irs = (1 + nm_isqrt(2 * ips - 1)) >> 1;
        iphi = 4 * irs + 1 - (ips - 2 * irs * (irs - 1));
        nr = irs;
        iring = 4 * n - irs;
        face = (iphi - 1) / irs + 8;
    }
    int irt = iring - NM_JRLL[face] * n + 1;
    int ipt = 2 * iphi - NM_JPLL[face] * nr - kshift - 1;
    if (ipt >= 4 * n) ipt -= 8 * n;
    ix = (ipt - irt) >> 1;
    iy = (-ipt - irt) >> 1;
}

// id of the first vertex on vertex ring r (0 .. 4n)
int nm_ring_start(int r) {
    const int n = NM_NSIDE;
    int s = 4 * n - r;
    if (r == 0) return 0;
    if (r <= n) return 1 + 2 * r * (r - 1);
    if (r >= 3 * n) return 12 * n * n + 1 - 2 * s * (s + 1);
    return 1 + 2 * n * (n - 1) + 4 * n * (r - n);
}

// vertex id of the face point (x, y) in [0, n]^2
int nm_xyf2vertex(int x, int y, int face) {
    const int n = NM_NSIDE;
    int r = NM_JRLL[face] * n - x - y;
    int nr = r < n ? r : (r > 3 * n ? 4 * n - r : n);
    if (nr == 0) return nm_ring_start(r);
    int count = 4 * nr;
    return nm_ring_start(r) + nm_mod(nm_mod(NM_JPLL[face] * nr + x - y, 2 * count) / 2, count);
}

// vertex ids of the corners of the level-`level` ancestor of ring pixel pix (neumat.nn.healpix._corner_vertices)
ivec4 nm_corner_vertices(int pix, int level) {
    int ix, iy, face;
    nm_ring2xyf(pix, ix, iy, face);
    int x0 = (ix >> level) << level, y0 = (iy >> level) << level, s = 1 << level;
    return ivec4(nm_xyf2vertex(x0 + s, y0 + s, face), nm_xyf2vertex(x0, y0 + s, face),
                 nm_xyf2vertex(x0, y0, face), nm_xyf2vertex(x0 + s, y0, face));
}
"""


def _table(values: torch.Tensor, row: int = 1) -> np.ndarray:
    """Values (M, row) -> float32 (1, rows, width, 4): each row of `row` values in ceil(row / 4) consecutive texels
    (zero-padded), rows packed `TABLE_WIDTH // ceil(row / 4)` to a texture row (so none straddles two), width that
    many times ceil(row / 4). With row = 1: value m at texel m // 4, component m % 4."""
    flat = values.detach().double().reshape(-1, row).cpu()
    if not torch.isfinite(flat).all():
        raise InputError("export_glsl: a NeuBRDF table has non-finite values; the model cannot be exported")
    if row == 1:
        flat = flat.reshape(-1, 4 * TABLE_WIDTH) if len(flat) % (4 * TABLE_WIDTH) == 0 else \
            torch.cat([flat.flatten(), flat.new_zeros(-len(flat) % (4 * TABLE_WIDTH))]).reshape(-1, 4 * TABLE_WIDTH)
        return flat.float().view(1, -1, TABLE_WIDTH, 4).numpy()
    texels = -(-row // 4)
    per_row = _per_row(texels)
    rows = max(1, -(-len(flat) // per_row))
    out = torch.zeros(rows * per_row, texels * 4, dtype=torch.float64)
    out[:len(flat), :row] = flat
    return out.float().view(1, rows, per_row * texels, 4).numpy()


def _per_row(texels: int) -> int:
    """Table rows of `texels` texels each per texture row (`_table`)."""
    if texels > TABLE_WIDTH:
        raise InputError(f"export_glsl: a NeuBRDF table row of {texels} texels exceeds {TABLE_WIDTH}")
    return TABLE_WIDTH // texels


def _fetch(name: str) -> str:
    return f"""
uniform sampler2DArray {name};
float {name}_at(int m) {{
    int t = m >> 2;
    return texelFetch({name}, ivec3(t % {TABLE_WIDTH}, t / {TABLE_WIDTH}, 0), 0)[m & 3];
}}
"""


def _rows(name: str, texels: int) -> str:
    """GLSL of a `_table` of rows `texels` texels wide: `ivec2 <name>_row(int r)`, the texel of row r's first
    value; its others follow along x."""
    per_row = _per_row(texels)
    return f"""
uniform sampler2DArray {name};
ivec2 {name}_row(int r) {{ return ivec2((r % {per_row}) * {texels}, r / {per_row}); }}
"""


def _texel(name: str, at: str, j: int) -> str:
    return f"texelFetch({name}, ivec3({at}.x + {j}, {at}.y, 0), 0)"


_HD = """
// Config.direction_inputs "hd": the Rusinkiewicz half vector h and difference vector d (wi in the frame whose
// pole is h, x axis towards phi_h: neumat.core.coords.io_to_hd), as hd[0] = (h, d.x), hd[1] = (d.y, d.z, 0, 0);
// "hd_warp" (NM_HD_WARP defined): (h.x, h.y) rescaled to length sqrt(theta_h / (pi / 2))
// (neumat.methods.neubrdf.model.direction_inputs)
void nm_hd(vec3 wi, vec3 wo, out vec4 hd[2]) {
    vec3 h = wi + wo;
    h = h / max(length(h), 1e-12);
    float st = length(h.xy), cp = 1.0, sp = 0.0;
    if (st > 0.0) { cp = h.x / st; sp = h.y / st; }
    float a = cp * wi.x + sp * wi.y;
#ifdef NM_HD_WARP
    float r = sqrt(atan(st, h.z) / 1.5707963267948966);
    hd[0] = vec4(cp * r, sp * r, h.z, h.z * a - st * wi.z);
#else
    hd[0] = vec4(h, h.z * a - st * wi.z);
#endif
    hd[1] = vec4(cp * wi.y - sp * wi.x, st * a + h.z * wi.z, 0.0, 0.0);
}
"""

#: GLSL of the MLP's hidden activations on a vec4 (leaky ReLU: max(x, 0.01 x) is x for x >= 0, 0.01 x below)
ACTIVATIONS4 = {
    "relu": "vec4 nm_act4(vec4 x) { return max(x, 0.0); }",
    "leaky_relu": "vec4 nm_act4(vec4 x) { return max(x, 0.01 * x); }",
    "silu": "vec4 nm_act4(vec4 x) { return x / (1.0 + exp(-x)); }",
    "tanh": "vec4 nm_act4(vec4 x) { return tanh(x); }",
    "sigmoid": "vec4 nm_act4(vec4 x) { return 1.0 / (1.0 + exp(-x)); }",
    "softplus": "vec4 nm_act4(vec4 x) { return vec4(nm_softplus(x.x), nm_softplus(x.y), nm_softplus(x.z), "
                "nm_softplus(x.w)); }",
}


def hemisphere_pixels(nside: int) -> int:
    """Ring pixels 0 .. P-1 that a direction with z >= 0 can fall in: the rings down to the one below the equator
    (ring 2 N_side + 1, whose pixels touch z = 0), P = 2 N (N - 1) + 4 N (N + 2), all 12 N^2 pixels for N <= 1."""
    n = nside
    return min(12 * n * n, 2 * n * (n - 1) + 4 * n * (n + 2))


def export_neubrdf(model: NeuBRDF) -> GLSLExport:
    """GLSL source and tables of a NeuBRDF model (module docstring)."""
    if not isinstance(model, NeuBRDF):
        raise InputError(f"export_neubrdf: expected a NeuBRDF model, got {type(model).__name__}")
    cfg = model.cfg
    if cfg.activation not in ACTIVATIONS:
        raise InputError(f"export_glsl: NeuBRDF with activation {cfg.activation!r} has no GLSL export "
                         f"(supported: {', '.join(ACTIVATIONS)})")
    n, k = cfg.nside, cfg.feature_dim
    vq = isinstance(model.grid, VQFeatures)
    pruned = model._pruning is not None
    uniform = cfg.interpolation == "uniform"
    hidden = model.mlp.linears()[0].out_features
    k4, h4 = -(-k // 4), -(-hidden // 4)
    textures: dict[str, np.ndarray] = {}
    parts = [_COMMON, f"const int NM_NSIDE = {n};\nconst int NM_SOUTH_OFFSET = {hpx.south_grid_offset(n)};\n"
             f"const int NM_PIXELS = {12 * n * n};", _HEALPIX, ACTIVATIONS[cfg.activation],
             ACTIVATIONS4[cfg.activation]]
    with torch.no_grad():
        if uniform:  # the runtime's per-pixel first-layer table, hemisphere pixels of S+ then of (unmirrored) S-
            p = hemisphere_pixels(n)
            first = {}
            # the fp16 form's table: computed from the halves it stores (a runtime model's floats are halves)
            for precision, source in (("fp32", model), ("fp16", model if model.is_runtime else half_rounded(model))):
                table = source.pixel_first_layer_table()
                first[precision] = _table(torch.cat([table[:p], table[12 * n * n:12 * n * n + p]]), hidden)
            textures["nbrdf_first"] = first["fp32"]
            parts.append(f"const int NM_HEMISPHERE_PIXELS = {p};" + _rows("nbrdf_first", h4))
        else:
            if vq:
                textures["nbrdf_index"] = _table(model.grid.indices().double())
                textures["nbrdf_features"] = _table(model.grid.codebook, k)
            else:  # the decoded feature of every slot, exactly what eval reads
                textures["nbrdf_features"] = _table(model.grid(torch.arange(model.grid.num_vertices,
                                                                            device=model.level_i.device)), k)
            if pruned:
                textures["nbrdf_levels"] = _table(torch.cat([model._pruning[0], model._pruning[1]]).double())
            dirs = hpx.vertex2vec(n, torch.arange(hpx.nvertices(n)), torch.float32)
            textures["nbrdf_vertices"] = _table(dirs, 3)
            if vq:
                parts.append(_fetch("nbrdf_index"))
            if pruned:
                parts.append(_fetch("nbrdf_levels"))
            parts += [_rows("nbrdf_features", k4), _rows("nbrdf_vertices", 1)]
            row = "int(nbrdf_index_at(slot))" if vq else "slot"
            level = "int(nbrdf_levels_at(pix + (south ? NM_PIXELS : 0)))" if pruned else "0"
            reads = "\n".join(f"        psi[{j}] += a * {_texel('nbrdf_features', 'r', j)};" for j in range(k4))
            parts.append(f"""
// psi(w): corner features of w's pixel on S+ (south false) or of its mirror image on S-, weighted by inverse
// great-circle distance; features in vec4s (psi[j] holds features 4 j .. 4 j + 3)
void nm_lookup(vec3 w, bool south, out vec4 psi[{k4}]) {{
    w = vec3(w.xy, south ? -max(w.z, 0.0) : max(w.z, 0.0));
    int pix = nm_vec2pix(w);
    ivec4 vid = nm_corner_vertices(pix, {level});
    vec4 weights;
    for (int t = 0; t < 4; ++t) {{
        vec3 c = {_texel('nbrdf_vertices', 'nbrdf_vertices_row(vid[t])', 0)}.xyz;
        weights[t] = 1.0 / max(atan(length(cross(w, c)), dot(w, c)), 1e-7);
    }}
    weights /= weights.x + weights.y + weights.z + weights.w;
    for (int j = 0; j < {k4}; ++j) psi[j] = vec4(0.0);
    for (int t = 0; t < 4; ++t) {{
        int slot = vid[t] + (south ? NM_SOUTH_OFFSET : 0);
        ivec2 r = nbrdf_features_row({row});
        float a = weights[t];
{reads}
    }}
}}
""")
    c = cfg.texture_channels
    textured = model.texture is not None
    if textured:
        src, tex = pyramid_reader([level.detach() for level in model.texture.levels], None)
        parts.append(src)
        textures.update(tex)
    layers_z = -(-c // 4)
    z_param = f", vec4 z[{layers_z}]" if textured else ""
    kind = cfg.direction_inputs
    extra = DIRECTION_INPUTS[kind]
    if extra:
        parts.append(("#define NM_HD_WARP\n" if kind == "hd_warp" else "") + _HD)
    more = (vec4_components([f"z[{i}]" for i in range(layers_z)], c) +
            vec4_components(["hd[0]", "hd[1]"], extra))
    hd_code = "    vec4 hd[2];\n    nm_hd(wi, wo, hd);\n" if extra else ""
    if uniform:
        lookup = """    ivec2 ri = nbrdf_first_row(nm_vec2pix(vec3(wi.xy, max(wi.z, 0.0))));
    ivec2 ro = nbrdf_first_row(NM_HEMISPHERE_PIXELS + nm_vec2pix(vec3(wo.xy, max(wo.z, 0.0))));
"""
        init = [f"{_texel('nbrdf_first', 'ri', j)} + {_texel('nbrdf_first', 'ro', j)}" for j in range(h4)]
        consts, body, out = mlp_vec4("NM_L", model.mlp, more, "nm_act4", init, slice(2 * k, None))
    else:
        lookup = f"""    vec4 pi_[{k4}], po[{k4}];
    nm_lookup(wi, false, pi_);
    nm_lookup(wo, true, po);
"""
        inputs = (vec4_components([f"pi_[{j}]" for j in range(k4)], k)
                  + vec4_components([f"po[{j}]" for j in range(k4)], k) + more)
        consts, body, out = mlp_vec4("NM_L", model.mlp, inputs, "nm_act4")
    parts.append("\n".join(consts))
    parts.append(f"""
vec3 nm_decode(vec3 wi, vec3 wo{z_param}) {{
{lookup}{hd_code}{body}    return exp({out[0]});
}}
""")
    if textured:
        parts.append(f"""
vec3 neumat_eval_lod(vec3 wi, vec3 wo, vec2 uv, float lod) {{
    if (wi.z <= 0.0 || wo.z <= 0.0) return vec3(0.0);
    vec4 z[{layers_z}];
    nm_spatial_lod(uv, lod, z);
    return nm_decode(wi, wo, z);
}}

vec3 neumat_eval(vec3 wi, vec3 wo, vec2 uv) {{ return neumat_eval_lod(wi, wo, uv, 0.0); }}

vec3 neumat_eval(vec3 wi, vec3 wo, vec2 uv, mat2 footprint) {{ return neumat_eval_lod(wi, wo, uv, 0.0); }}
""")
        entry = ["vec3 neumat_eval(vec3 wi, vec3 wo, vec2 uv)",
                 "vec3 neumat_eval_lod(vec3 wi, vec3 wo, vec2 uv, float lod)",
                 "vec3 neumat_eval(vec3 wi, vec3 wo, vec2 uv, mat2 footprint)"]
    else:
        parts.append("""
vec3 neumat_eval(vec3 wi, vec3 wo) {
    if (wi.z <= 0.0 || wo.z <= 0.0) return vec3(0.0);
    return nm_decode(wi, wo);
}
""")
        entry = ["vec3 neumat_eval(vec3 wi, vec3 wo)"]
    header = (f"// neumat GLSL export of a 'neubrdf' model (N_side {n}, k {k}, {cfg.features} features, "
              f"{'first-layer table of uniform' if uniform else 'inverse-distance'} corner weights"
              f"{', pruned' if pruned else ''}{', neural texture' if textured else ''}"
              f"{', direction inputs h, d' if extra else ''}); see neumat.methods.neubrdf.glsl.\n")
    exact = tuple(name for name in ("nbrdf_first", "nbrdf_index", "nbrdf_levels", "nbrdf_vertices")
                  if name in textures)
    return GLSLExport(header + "\n".join(parts), textures, textured, entry, exact=exact,
                      fp16_textures={"nbrdf_first": first["fp16"]} if uniform else {})
