"""GLSL generator of the multi-scale models (Timonen et al. 2025, Sec. 5.3): the gated model, its homogeneous
variant and the configurations built on it (tripleplane, the ablations); format in `neumat.export.glsl`."""
from __future__ import annotations

import math

import torch

from neumat.core.errors import InputError
from neumat.methods.latent_mlp.multiscale import MultiScale
from neumat.nn.radial_warp import MIN_ALPHA
from neumat.export.glsl_common import (_COMMON, GLSLExport, _angular_reader, _floats, _layers, _linear,
                          _spatial_reader, mlp_chain, shading_frames, spatial_entry_points)


def export_multiscale(model: MultiScale) -> GLSLExport:
    """GLSL source and textures computing `model.eval` of a MultiScale (`neumat.export.glsl`)."""
    if not isinstance(model, MultiScale):
        raise InputError(f"export_glsl: expected a multi-scale model (multiscale, tripleplane), got "
                         f"{type(model).__name__} ({getattr(model, 'name', '?')})")
    cfg = model.cfg
    spatial = model.spatial is not None
    gated = spatial and cfg.gating
    ds = cfg.spatial_channels
    zl = -(-ds // 4)  # spatial latent layers
    consts, textures, parts = [], {}, [_COMMON]
    zs = "z[i / 4][i % 4]"  # z_s[i] in a vec4 array `z`

    if spatial:
        src, tex = _spatial_reader(model)
        parts.append(src)
        textures.update(tex)
    with torch.no_grad():
        for tex_name, module, channels in (("neumat_half", model.half_texture, model.half_texture.channels),
                                           ("neumat_diff", model.diff_texture, model.diff_texture.channels)):
            textures[tex_name] = _layers(module.texture())
            parts.append(f"uniform sampler2DArray {tex_name};")
            parts.append(_angular_reader(f"nm_read_{tex_name[7:]}", tex_name, channels, module.radial,
                                         module.angular, module.period))

    decode = []  # body of nm_decode(wi, wo, z)
    if model.frame is not None:
        frame_consts, frame_code = shading_frames(model.frame, ds, zs)
        consts += frame_consts
        decode.append(frame_code + "    wi = di[0];\n    wo = dw[0];\n")
    else:
        decode.append("    wi = nm_lift(wi);\n    wo = nm_lift(wo);\n")
    decode.append(f"""    vec3 h, d;
    nm_half_difference(wi, wo, h, d);
    vec2 ph = nm_disk_polar(h, {2 * math.pi:.9e});
    vec2 pd = nm_disk_polar(d, {math.pi:.9e});
""")
    if model.warp_h is not None:
        k = cfg.warp_terms
        for tag, warp, coord in (("H", model.warp_h, "ph"), ("D", model.warp_d, "pd")):
            if warp.latent_dim > 0:
                consts += [_floats(f"NM_WARP{tag}_W", warp.decode.weight), _floats(f"NM_WARP{tag}_B", warp.decode.bias)]
                decode.append(f"    float w{tag}[{2 * k}];\n" + _linear(f"NM_WARP{tag}", 2 * k, ds, zs, f"w{tag}"))
            else:
                consts.append(_floats(f"NM_WARP{tag}_P", warp.params))
                decode.append(f"    float w{tag}[{2 * k}];\n    for (int i = 0; i < {2 * k}; ++i) "
                              f"w{tag}[i] = NM_WARP{tag}_P[i];\n")
            decode.append(f"""    {{
        float top = w{tag}[0];
        for (int i = 1; i < {k}; ++i) top = max(top, w{tag}[i]);
        float total = 0.0, acc = 0.0, r = clamp({coord}.x, 1e-9, 1.0);
        for (int i = 0; i < {k}; ++i) {{
            float e = exp(w{tag}[i] - top);
            total += e;
            acc += e * exp(({MIN_ALPHA:.9e} + nm_softplus(w{tag}[{k} + i])) * log(r));
        }}
        {coord}.x = acc / total;
    }}
""")
    hl, dl = -(-model.half_texture.channels // 4), -(-model.diff_texture.channels // 4)
    decode.append(f"    vec4 ah[{hl}], ad[{dl}];\n"
                  "    nm_read_half(ph.x, ph.y, ah);\n    nm_read_diff(pd.x, pd.y, ad);\n")
    mlp = model.mlp.linears()
    in_dim = mlp[0].in_features
    decode.append(f"    float x[{in_dim}];\n")
    dh, dd = cfg.half_channels, cfg.diff_channels
    if gated:
        decode.append(f"""    for (int o = 0; o < {dh}; ++o) {{
        float acc = 0.0;
        for (int i = 0; i < {ds}; ++i) {{ int c = o * {ds} + i; acc += ah[c / 4][c % 4] * {zs}; }}
        x[o] = acc;
    }}
    for (int o = 0; o < {dd}; ++o) {{
        float acc = 0.0;
        for (int i = 0; i < {ds}; ++i) {{ int c = o * {ds} + i; acc += ad[c / 4][c % 4] * {zs}; }}
        x[{dh} + o] = acc;
    }}
""")
    else:
        decode.append(f"    for (int i = 0; i < {dh}; ++i) x[i] = ah[i / 4][i % 4];\n"
                      f"    for (int i = 0; i < {dd}; ++i) x[{dh} + i] = ad[i / 4][i % 4];\n")
        if spatial:
            decode.append(f"    for (int i = 0; i < {ds}; ++i) x[{dh + dd} + i] = {zs};\n")
    mlp_consts, mlp_body, out = mlp_chain("NM_L", model.mlp, "x[i]", "nm_silu")
    consts += mlp_consts
    f = f"exp(vec3({out}[0], {out}[1], {out}[2]))"
    bound = model.output_bound_values()  # the fitted model's output bound (multiscale.Config.output_bound)
    if bound is not None:
        f = f"min({f}, vec3({', '.join(format(b, '.9e') for b in bound)}))"
    decode.append(mlp_body + f"    return {f};\n")

    z_param = f", vec4 z[{zl}]" if spatial else ""
    parts.append("\n".join(consts))
    parts.append(f"vec3 nm_decode(vec3 wi, vec3 wo{z_param}) {{\n" + "".join(decode) + "}\n")
    if spatial:
        parts.append(spatial_entry_points(zl))
    else:
        parts.append("""
vec3 neumat_eval(vec3 wi, vec3 wo) {
    if (wi.z <= 0.0 || wo.z <= 0.0) return vec3(0.0);
    return nm_decode(wi, wo);
}
""")
    header = (f"// neumat GLSL export of a '{model.name}' model ({'gated' if gated else 'concatenated latents'}"
              f"{', spatially varying' if spatial else ', homogeneous'}); see neumat.export.glsl.\n")
    return GLSLExport(header + "\n".join(parts), textures, spatial)
