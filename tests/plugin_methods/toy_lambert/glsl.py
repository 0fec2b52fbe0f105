"""GLSL of the toy method: one constant."""
import math

from neumat.export.glsl_common import GLSLExport


def export_toy_lambert(model) -> GLSLExport:
    a = (model.log_albedo.detach().exp() / math.pi).tolist()
    source = (f"const vec3 TOY_F = vec3({a[0]:.9e}, {a[1]:.9e}, {a[2]:.9e});\n"
              "vec3 neumat_eval(vec3 wi, vec3 wo) { return (wi.z > 0.0 && wo.z > 0.0) ? TOY_F : vec3(0.0); }\n")
    return GLSLExport(source, spatially_varying=False)
