"""Issue 49: what NeuBRDF's GLSL export (runtime form, fp32) gains on llvmpipe from the changes a shader can make,
each an edit of the exported source measured beside the shipped one: evaluations per CPU second
(`neumat.testing.parity.glsl_evals_per_second`, one llvmpipe thread) at 2^16 random cosine-weighted queries, and
the largest relative error against the torch runtime on 4096 of them. Variants:

- `fma`: every multiply-add of the MLP as `fma()`, under `#version 400 core`;
- `group-loop`: the hidden layer as a loop over its 16 output groups reading `const vec4` weights;
- `packed-halves`: the first-layer table as halves packed in an RGBA32UI texture (8 fetches a row instead of 16),
  decoded by bit operations (subnormal halves flushed to 0);
- `ssbo`, `ssbo-packed`: the first-layer table (float32, or the packed halves) in a shader storage buffer read by
  index (`#version 430 core`) instead of a texture;
- `uniform` (with --slow: Mesa compiles it for minutes): the weights as a `uniform vec4` array;
- `cached`: the shipped shader at queries from 8 directions, so every table row it reads is in cache.

Conclusions: src/neumat/methods/neubrdf/NOTES.md, the GLSL export row.
Usage: python -m benchmarks.studies.speed.glsl_neubrdf_variants [--rounds 2] [--slow]
"""
from __future__ import annotations

import argparse
import dataclasses
import os
import re
import sys
from typing import Callable

os.environ.setdefault("LP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import torch  # noqa: E402

from benchmarks.suites.speed import queries, runtime_model  # noqa: E402
from neumat.core.query import Query  # noqa: E402
from neumat.export import glsl_common  # noqa: E402
from neumat.export.half_precision import pack_halves  # noqa: E402
from neumat.methods.neubrdf import glsl as neubrdf_glsl  # noqa: E402
from neumat.testing import parity  # noqa: E402

_VERSION_400 = "#version 400 core"
_VERSION_430 = "#version 430 core"
_HIDDEN_GROUPS, _HIDDEN = 16, 64


def _floats(source: str, name: str) -> np.ndarray:
    body = re.search(rf"const float {name}\[\d+\] = float\[\]\(([^)]*)\);", source).group(1)
    return np.array([float(x) for x in body.split(",")], np.float32)


def _fma(source: str) -> str:
    """Each `a + x * vecN(...)` chain of the unrolled layers as `a = fma(vecN(x), vecN(...), a)` statements."""
    def chain(m):
        vec, var, start, terms = m.group(1), m.group(2), m.group(3), m.group(4).split("\n        + ")[1:]
        out = f"    {vec} {var} = {start};\n"
        for t in terms:
            x, w = t.split(" * ", 1)
            out += f"    {var} = fma({vec}({x}), {w}, {var});\n"
        return out
    return re.sub(r"    (vec[34]) (nm_l\d+_\d+) = ([^\n]*)((?:\n        \+ [^\n;]*)+);\n", chain, source)


def _group_loop(source: str) -> str:
    w = _floats(source, "NM_L1_W").reshape(_HIDDEN, _HIDDEN)
    b = _floats(source, "NM_L1_B")
    f = lambda v: "%.9e" % v  # noqa: E731
    w4 = ", ".join(f"vec4({', '.join(f(w[4 * g + r, i]) for r in range(4))})"
                   for g in range(_HIDDEN_GROUPS) for i in range(_HIDDEN))
    b4 = ", ".join(f"vec4({', '.join(f(b[4 * g + r]) for r in range(4))})" for g in range(_HIDDEN_GROUPS))
    inputs = [f"nm_l0_{j}.{c}" for j in range(_HIDDEN_GROUPS) for c in "xyzw"]
    loop = (f"    vec4 nm_l1[{_HIDDEN_GROUPS}];\n    for (int g = 0; g < {_HIDDEN_GROUPS}; ++g) {{\n"
            "        vec4 a = NM_B1[g]" + "".join(f"\n            + {x} * NM_W1[g * {_HIDDEN} + {i}]"
                                              for i, x in enumerate(inputs))
            + ";\n        nm_l1[g] = nm_act4(a);\n    }\n")
    start, end = source.index("    vec4 nm_l1_0 = "), source.index("    vec3 nm_l2_0 = ")
    out = source[:start] + loop + re.sub(r"nm_l1_(\d+)\.", r"nm_l1[\1].", source[end:])
    consts = f"const vec4 NM_W1[{len(inputs) * _HIDDEN_GROUPS}] = vec4[]({w4});\nconst vec4 NM_B1[16] = vec4[]({b4});"
    return re.sub(r"const float NM_L1_W\[\d+\] = float\[\]\([^)]*\);", consts, out)


def _uniform(source: str) -> tuple[str, np.ndarray]:
    arrays = {name: _floats(source, name) for name in ("NM_L1_W", "NM_L2_W")}
    vecs: list[list[float]] = []

    def vec(m):
        values = [arrays[a][int(i)] for a, i in re.findall(r"(NM_L\d_W)\[(\d+)\]", m.group(2))]
        vecs.append(values + [0.0] * (4 - len(values)))
        return f"NM_V[{len(vecs) - 1}]" + ("" if m.group(1) == "vec4" else ".xyz")
    out = re.sub(r"(vec4|vec3)\(((?:NM_L\d_W\[\d+\](?:, )?)+)\)", vec, source)
    out = re.sub(r"const float NM_L\d_W\[\d+\] = float\[\]\([^)]*\);\n", "", out)
    return f"uniform vec4 NM_V[{len(vecs)}];\n" + out, np.array(vecs, np.float32)


_SHIPPED_TABLE = ("uniform sampler2DArray nbrdf_first;\n"
                  "ivec2 nbrdf_first_row(int r) { return ivec2((r % 64) * 16, r / 64); }")
_HALF4 = ("vec4 nm_h4(uvec2 w) {\n    uvec4 h = uvec4(w.x & 65535u, w.x >> 16u, w.y & 65535u, w.y >> 16u);\n"
          "    return uintBitsToFloat(((h & 32768u) << 16u) | ((h & 32767u) << 13u)) * 5.192296858534828e+33;\n}")


def _packed_fetches(read: Callable[[str, int], str]) -> Callable:
    """re.sub callback: the first-layer group nm_l0_j from packed halves, 8 per texel (read(row, texel) is the
    uvec4 at texel `texel` of table row ri or ro), each texel read once."""
    def group(m):
        j = int(m.group(1))
        t, part = j // 2, ("xy" if j % 2 == 0 else "zw")
        fetch = "" if part == "zw" else f"    uvec4 nm_ti{t} = {read('ri', t)}, nm_to{t} = {read('ro', t)};\n"
        return fetch + f"    vec4 nm_l0_{j} = nm_h4(nm_ti{t}.{part}) + nm_h4(nm_to{t}.{part});\n"
    return group


def _packed_table(table: np.ndarray) -> np.ndarray:
    """The float32 table (1, rows, width, 4) as halves packed two to a uint32 (1, rows, width / 2, 4); subnormal
    halves flushed to 0 (the decode is one multiply, not nm_half's branches)."""
    layers, rows, width, _ = table.shape
    h = table.reshape(layers, rows, width // 16, 64).astype(np.float16)
    h[np.abs(h) < np.float16(2 ** -14)] = 0
    return pack_halves(h.ravel()).reshape(layers, rows, width // 2, 4)


def _ssbo(source: str, packed: bool) -> str:
    """The table as a `readonly buffer` of vec4 (or uvec4 of packed halves), row r at element r * 16 (r * 8)."""
    per_row = 8 if packed else 16
    out = source.replace(_SHIPPED_TABLE, "layout(std430, binding = 0) readonly buffer NbrdfFirst { "
                         f"{'uvec4' if packed else 'vec4'} nbrdf_first_data[]; }};\n"
                         f"int nbrdf_first_row(int r) {{ return r * {per_row}; }}" + ("\n" + _HALF4 if packed else ""))
    out = re.sub(r"ivec2 (r[io]) = nbrdf_first_row", r"int \1 = nbrdf_first_row", out)
    if packed:
        return re.sub(r"    vec4 nm_l0_(\d+) = texelFetch\(nbrdf_first, [^;]*;\n",
                      _packed_fetches(lambda row, t: f"nbrdf_first_data[{row} + {t}]"), out)
    return re.sub(r"texelFetch\(nbrdf_first, ivec3\((r[io])\.x \+ (\d+), r[io]\.y, 0\), 0\)",
                  r"nbrdf_first_data[\1 + \2]", out)


def _packed_halves(source: str, table: np.ndarray) -> tuple[str, np.ndarray]:
    """The table as packed halves in an RGBA32UI texture (8 fetches a row instead of 16): (source, its table)."""
    out = source.replace(_SHIPPED_TABLE, "uniform usampler2DArray nbrdf_first;\n"
                         "ivec2 nbrdf_first_row(int r) { return ivec2((r % 64) * 8, r / 64); }\n" + _HALF4)
    read = lambda row, t: f"texelFetch(nbrdf_first, ivec3({row}.x + {t}, {row}.y, 0), 0)"  # noqa: E731
    return re.sub(r"    vec4 nm_l0_(\d+) = texelFetch\(nbrdf_first, [^;]*;\n", _packed_fetches(read), out), \
        _packed_table(table)


def _with_uploads(uniform: np.ndarray | None = None, uint_table: np.ndarray | None = None,
                  storage: np.ndarray | None = None):
    """parity's context factory, its programs given the uniform array NM_V, its RGBA32UI table and the shader
    storage buffer at binding 0."""
    make = parity._context

    def context(backend):
        moderngl, ctx = make(backend)
        if storage is not None:
            ctx.nm_storage = ctx.buffer(np.ascontiguousarray(storage).tobytes())
            ctx.nm_storage.bind_to_storage_buffer(0)
        program, texture_array = ctx.program, ctx.texture_array

        def program_(**kw):
            p = program(**kw)
            if uniform is not None and "NM_V" in p:
                p["NM_V"].write(uniform.tobytes())
            return p

        def texture_array_(size, components, data, dtype):
            if uint_table is not None and size[0] == uint_table.shape[2]:
                return texture_array(size, components, np.ascontiguousarray(uint_table).tobytes(), dtype="u4")
            return texture_array(size, components, data, dtype=dtype)
        ctx.program, ctx.texture_array = program_, texture_array_
        return moderngl, ctx
    return context


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--slow", action="store_true", help="also the uniform-array variant (minutes to compile)")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    model = runtime_model("neubrdf", 0)
    q = queries(model, 2 ** 16, 0)
    pick = torch.randint(0, 8, (len(q.wi),), generator=torch.Generator().manual_seed(1))
    cached = Query(q.wi[:8][pick], q.wo[:8][pick.flip(0)])
    shipped = neubrdf_glsl.export_neubrdf(model)
    source = shipped.source
    packed_source, packed = _packed_halves(source, shipped.textures["nbrdf_first"])
    # (name, export, queries, #version, context factory)
    variants = [("shipped", shipped, q, glsl_common.GLSL_VERSION, parity._context),
                ("fma", dataclasses.replace(shipped, source=_fma(source)), q, _VERSION_400, parity._context),
                ("group-loop", dataclasses.replace(shipped, source=_group_loop(source)), q, glsl_common.GLSL_VERSION,
                 parity._context),
                ("packed-halves", dataclasses.replace(shipped, source=packed_source, textures={"nbrdf_first": packed}),
                 q, glsl_common.GLSL_VERSION, _with_uploads(uint_table=packed)),
                ("ssbo", dataclasses.replace(shipped, source=_ssbo(source, False), textures={}), q, _VERSION_430,
                 _with_uploads(storage=shipped.textures["nbrdf_first"])),
                ("ssbo-packed", dataclasses.replace(shipped, source=_ssbo(source, True), textures={}), q, _VERSION_430,
                 _with_uploads(storage=packed)),
                ("cached", shipped, cached, glsl_common.GLSL_VERSION, parity._context)]
    if args.slow:
        uniform_source, uniform = _uniform(source)
        variants.append(("uniform", dataclasses.replace(shipped, source=uniform_source), q, glsl_common.GLSL_VERSION,
                         _with_uploads(uniform=uniform)))
    fragment, vertex, context = parity._FRAGMENT, parity._VERTEX, parity._context
    print("variant        max rel err   evals / CPU s", flush=True)
    try:
        for _ in range(args.rounds):
            for name, export, qq, version, make in variants:
                parity._FRAGMENT = fragment.replace(glsl_common.GLSL_VERSION, version, 1)
                parity._VERTEX = vertex.replace(glsl_common.GLSL_VERSION, version, 1)
                parity._context = make
                with torch.no_grad():
                    ref = model.eval(qq[:4096])
                got = parity.glsl_eval(export, qq[:4096])
                err = float(((got - ref).abs() / ref.abs().clamp(min=1e-3)).max())
                rate = parity.glsl_evals_per_second(export, qq, clock="cpu", repeats=5)
                print(f"{name:14s} {err:11.2g}   {rate:.3g}", flush=True)
    finally:
        parity._FRAGMENT, parity._VERTEX, parity._context = fragment, vertex, context
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
