"""GGX in GLSL, the analytic yardstick of the shader speed table (issue 49): `ggx_glsl(material)` is a
`GLSLExport` computing what `neumat.reflectance.analytic.GGX.eval` computes for a conductor GGX (GGX D, Smith G1 of
both directions, the exact conductor Fresnel of `neumat.reflectance.microfacet.fresnel_conductor`, / 4 cos_i cos_o),
so that a neural shader's rate can be set beside GGX's in the same harness (`neumat.testing.parity.glsl_eval`)."""
from __future__ import annotations

from ..core.errors import InputError
from ..export.glsl_common import GLSLExport


def _vec3(values) -> str:
    return "vec3(" + ", ".join(f"{float(v):.9e}" for v in values) + ")"


def ggx_glsl(material) -> GLSLExport:
    """GLSL `vec3 neumat_eval(vec3 wi, vec3 wo)` of a conductor GGX material (`open_material("ggx:...")`)."""
    if getattr(material, "name", None) != "ggx" or getattr(material, "fresnel", None) != "conductor":
        raise InputError(f"ggx_glsl: expected a GGX material with fresnel='conductor', got {material!r}")
    ax, ay = float(material.alpha_x), float(material.alpha_y)
    eta, k = [float(v) for v in material.eta], [float(v) for v in material.k]
    source = f"""// GGX conductor (neumat.testing.glsl_ggx): alpha ({ax:g}, {ay:g})
const float NM_AX = {ax:.9e}, NM_AY = {ay:.9e};
const vec3 NM_ETA = {_vec3(eta)}, NM_K = {_vec3(k)};

float nm_g1(vec3 w) {{
    float z = max(w.z, 0.0);
    float root = sqrt(w.z * w.z + (NM_AX * w.x) * (NM_AX * w.x) + (NM_AY * w.y) * (NM_AY * w.y));
    return 2.0 * z / max(z + root, 1.17549435e-38);
}}

vec3 nm_fresnel_conductor(float c) {{
    c = clamp(c, 0.0, 1.0);
    vec3 eta2_minus_k2 = NM_ETA * NM_ETA - NM_K * NM_K, four_eta2_k2 = 4.0 * NM_ETA * NM_ETA * NM_K * NM_K;
    float c2 = c * c, s2 = 1.0 - c2;
    vec3 t1 = eta2_minus_k2 - s2;
    vec3 a2pb2 = sqrt(t1 * t1 + four_eta2_k2);
    vec3 a = sqrt(max(0.5 * (a2pb2 + t1), 0.0));
    vec3 term1 = a2pb2 + c2, term2 = (2.0 * c) * a;
    vec3 r_s = (term1 - term2) / (term1 + term2);
    vec3 term3 = a2pb2 * c2 + s2 * s2, term4 = term2 * s2;
    vec3 r_p = r_s * (term3 - term4) / (term3 + term4);
    return 0.5 * (r_s + r_p);
}}

vec3 neumat_eval(vec3 wi, vec3 wo) {{
    vec3 h = wi + wo;
    h = h / max(length(h), 1e-12);
    float q = (h.x / NM_AX) * (h.x / NM_AX) + (h.y / NM_AY) * (h.y / NM_AY) + h.z * h.z;
    float d = h.z > 0.0 ? 1.0 / (3.141592653589793 * NM_AX * NM_AY * q * q) : 0.0;
    float s = d * nm_g1(wi) * nm_g1(wo) / max(4.0 * wi.z * wo.z, 1.17549435e-38);
    return nm_fresnel_conductor(dot(wi, h)) * s;
}}
"""
    return GLSLExport(source, {}, False, ["vec3 neumat_eval(vec3 wi, vec3 wo)"])
