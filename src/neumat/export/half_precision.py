"""The fp16 form of a GLSL export (`neumat.export.glsl.export_glsl(model, precision="fp16")`, the default): the
latent textures and decoder weights stored in half precision, computed in float32, as the runtime of Real-Time
Neural Appearance Models (Zeltner et al. 2024, Sec. 7) infers in FP16.

`to_half(export)` rewrites an fp32 export: textures become RGBA16F, float constant arrays packed halves.

Details: docs/formats/glsl.md, section `neumat.export.half_precision`.
"""
from __future__ import annotations

import dataclasses
import re

import numpy as np

from ..core.errors import InputError
from ..models.half_precision import HALF_MAX
from .glsl_common import GLSLExport

#: GLSL of nm_half(h): the float value of the IEEE half whose bits are the low 16 bits of h (finite halves only)
HALF_GLSL = """
// the IEEE half in the low 16 bits of h as a float, exact for every finite half (subnormals included)
float nm_half(uint h) {
    uint e = (h >> 10u) & 31u, m = h & 1023u;
    float v = e == 0u ? float(m) * 5.9604644775390625e-8 : uintBitsToFloat(((e + 112u) << 23u) | (m << 13u));
    return (h & 32768u) != 0u ? -v : v;
}
"""

_ARRAY = re.compile(r"^const float (\w+)\[(\d+)\] = float\[\]\((.*)\);$", re.M)


def half_values(values: np.ndarray, what: str) -> np.ndarray:
    """float16 of `values`, rounded to nearest; InputError naming `what` if any is not finite or out of range."""
    with np.errstate(over="ignore"):
        half = np.asarray(values, np.float32).astype(np.float16)
    if not np.isfinite(half).all():
        raise InputError(f"export precision fp16: {what} has values that are not finite or exceed the float16 "
                         f"range (|x| <= {HALF_MAX:g}); export it with precision='fp32'")
    return half


def pack_halves(values: np.ndarray) -> np.ndarray:
    """uint32 words of float16 `values` (n,), two per word, element 2k in the low half; odd n padded with 0."""
    bits = np.zeros(len(values) + len(values) % 2, np.uint32)
    bits[:len(values)] = values.view(np.uint16)
    return bits[0::2] | (bits[1::2] << 16)


def _index_calls(source: str, name: str, accessor: str) -> str:
    """`source` with every `name[expr]` replaced by `accessor(expr)` (brackets matched)."""
    out, pos = [], 0
    pattern = re.compile(rf"\b{name}\[")
    while (m := pattern.search(source, pos)) is not None:
        depth, i = 1, m.end()
        while depth:
            depth += {"[": 1, "]": -1}.get(source[i], 0)
            i += 1
        out += [source[pos:m.start()], f"{accessor}(", source[m.end():i - 1], ")"]
        pos = i
    return "".join(out) + source[pos:]


def _literal(value: np.float16) -> str:
    """A GLSL float literal that parses (as float32) to exactly the half `value`."""
    text = repr(float(np.float32(value)))  # the shortest decimal of the value (exact in float32, as every half)
    text = text if "." in text or "e" in text else text + ".0"
    return f"({text})" if text.startswith("-") else text


def to_half(export: GLSLExport) -> GLSLExport:
    """The fp16 form of an fp32 `export` (module docstring); `export` is left unchanged."""
    if export.precision != "fp32":
        raise InputError(f"to_half: expected an fp32 export, got precision {export.precision!r}")
    header, body = export.source.split("\n", 1) if export.source.startswith("//") else ("", export.source)
    arrays = _ARRAY.findall(body)
    weights = 0
    for name, n, values in arrays:
        flat = np.array([float(v) for v in values.split(",")], np.float64)
        if len(flat) != int(n):
            raise InputError(f"to_half: array {name} declares {n} values and has {len(flat)}")
        weights += len(flat)
        half = half_values(flat, f"parameter {name}")
        marker = f"/* {name} */"
        body = body.replace(f"const float {name}[{n}] = float[]({values});", marker, 1)
        # reads at a literal index (unrolled code, `glsl_common.dense_vec4`) become the half's value as a literal,
        # what a compiler folds a constant read of the packed array into (Mesa takes minutes to fold 10^4 of them)
        body = re.sub(rf"\b{name}\[(\d+)\]", lambda m: _literal(half[int(m.group(1))]), body)
        packed = ""
        if re.search(rf"\b{name}\[", body):  # reads at computed indices: packed halves and their accessor
            words = pack_halves(half)
            packed = (f"const uint {name}_F16[{len(words)}] = uint[]({', '.join(f'0x{w:08x}u' for w in words)});\n"
                      f"float {name}_AT(int k) {{ uint w = {name}_F16[k >> 1]; "
                      f"return nm_half((k & 1) == 0 ? w & 65535u : w >> 16u); }}")
            body = _index_calls(body, name, f"{name}_AT")
        body = body.replace(marker, packed, 1)
    body = HALF_GLSL + body  # also read by the Slang spelling of half textures (`neumat.export.slang`)
    textures = {name: export.fp16_textures.get(name, data) if name in export.exact
                else half_values(data, f"texture {name}") for name, data in export.textures.items()}
    source = (header + "\n" if header else "") + body
    return dataclasses.replace(export, source=source, textures=textures, precision="fp16", weight_values=weights,
                               fp16_textures={})
