"""Run an exported GLSL material on an OpenGL context, for parity checks against the torch model.

`glsl_eval(export, q)` draws one fragment per query into an RGBA32F framebuffer: the fragment shader reads
its query (wi, wo, uv, footprint or lod) from float textures with `texelFetch`, calls the export's
`neumat_eval` and writes the value. `glsl_run(export, inputs, call)` does the same for any entry point
(the NeuPreSS export's, say). Each compiles the export under its fastest GLSL (`GLSLExport.fastest_glsl_version`: 4.20
where it reads images) or the `version` given. Needs `moderngl` and an OpenGL 3.3 context (4.2 for images); by
default a headless EGL one (Mesa llvmpipe runs it on the CPU).
"""
from __future__ import annotations

import math
import time

import numpy as np
import torch

from ..core.errors import InputError
from ..core.query import Query
from ..export.glsl_common import GLSL_IMAGE_VERSION, GLSL_VERSION, GLSLExport, glsl_version_number
from .timing import best_times

_VERTEX = GLSL_VERSION + """
in vec2 position;
void main() { gl_Position = vec4(position, 0.0, 1.0); }
"""

_FRAGMENT = GLSL_VERSION + """
{uniforms}
out vec4 colour;
{material}
void main() {{
    ivec2 p = ivec2(gl_FragCoord.xy);
{reads}
    {call}
}}
"""


def _context(backend: str | None):
    try:
        import moderngl
    except ImportError as e:  # pragma: no cover - moderngl is a dev dependency
        raise InputError("glsl_eval needs the 'moderngl' package (pip install moderngl)") from e
    return moderngl, moderngl.create_standalone_context(**({"backend": backend} if backend else {}))


def opengl_available(backend: str | None = "egl") -> bool:
    """Whether `glsl_eval` can run here: moderngl is installed and an OpenGL 3.3 context can be created."""
    try:
        _, ctx = _context(backend)
    except Exception:  # no moderngl, no driver, no display
        return False
    ctx.release()
    return True


def glsl_eval(export: GLSLExport, q: Query, backend: str | None = "egl", width: int = 256, entry: str = "eval",
              u: torch.Tensor | None = None, version: str | None = None) -> torch.Tensor:
    """Values (N, 3) of the exported material at the queries q (float32, on q's device). Spatially varying
    exports use q.footprint if given, else q.lod (0 when absent); they need q.uv. entry "pdf" (density in
    channel 0) and "sample" (wo for u (N, 2); q.wo unused) call the sampler entry points of exports that
    have them (with q.footprint). A NeuPreSS export gives S_hat at the object-space position q.x, as the Slang
    and Dr.Jit evaluators do. version: the #version line (default `export.fastest_glsl_version()`)."""
    n = len(q.wi)
    if n == 0:
        return q.wi.new_zeros(0, 3)
    if entry == "eval" and any("neumat_translucent" in e for e in export.entry or ()):
        q.require("x", who="glsl_eval (NeuPreSS export)")
        inputs = {"wi": q.wi, "x": q.x, "wo": q.wo}
        return glsl_run(export, inputs, _TRANSLUCENT_CALL, backend, width, version)[:, :3].to(q.wi.device)
    if entry not in ("eval", "pdf", "sample"):
        raise InputError(f"glsl_eval entry: expected 'eval', 'pdf' or 'sample', got {entry!r}")
    if entry != "eval":
        q.require("uv", "footprint", who=f"glsl_eval entry {entry!r}")
        if entry == "sample" and (u is None or u.shape != (n, 2)):
            raise InputError(f"glsl_eval entry 'sample': expected u of shape ({n}, 2)")
        fp = "mat2(f.x, f.y, f.y, f.z)"
        call = ("colour = vec4(neumat_pdf(wi, wo, uv, " + fp + "), 0.0, 0.0, 1.0);" if entry == "pdf" else
                "colour = vec4(neumat_sample(wi, uv, " + fp + ", wo.xy), 1.0);")
        mode = 0
    elif export.spatially_varying:
        q.require("uv", who="glsl_eval (spatially varying export)")
        if q.footprint is not None:
            call, mode = "colour = vec4(neumat_eval(wi, wo, uv, mat2(f.x, f.y, f.y, f.z)), 1.0);", 0
        else:
            call, mode = "colour = vec4(neumat_eval_lod(wi, wo, uv, f.w), 1.0);", 1
    else:
        call, mode = "colour = vec4(neumat_eval(wi, wo), 1.0);", 2
    filt = torch.zeros(n, 4)
    if mode == 0:
        fp = q.footprint.detach().float().cpu()
        filt[:, 0], filt[:, 1], filt[:, 2] = fp[:, 0, 0], fp[:, 0, 1], fp[:, 1, 1]
    elif mode == 1 and q.lod is not None:
        filt[:, 3] = q.lod.detach().float().cpu()
    uv = q.uv if export.spatially_varying else torch.zeros(n, 2)
    inputs = {"q_wi": q.wi, "q_wo": u if entry == "sample" else q.wo, "q_uv": uv, "q_filter": filt}
    call = "vec3 wi = q_wi.xyz, wo = q_wo.xyz; vec2 uv = q_uv.xy; vec4 f = q_filter;\n    " + call
    return glsl_run(export, inputs, call, backend, width, version)[:, :3].to(q.wi.device)


def glsl_evals_per_second(export: GLSLExport, q: Query, backend: str | None = "egl", clock: str = "wall",
                          repeats: int = 3, version: str | None = None) -> float | dict[str, float]:
    """Evaluations per second of `glsl_eval(export, q)` on this OpenGL (llvmpipe on a CPU-only machine), the
    `marginal_rate` (context creation, compilation and uploads do not count); per wall or per CPU second of this
    process (`clock` "cpu": llvmpipe's threads included, a loaded machine's waits not; "both": a dict of the two),
    under `version` (default: the export's fastest, `GLSLExport.fastest_glsl_version`)."""
    return marginal_rate(lambda part: glsl_eval(export, part, backend, version=version), q, "glsl_evals_per_second",
                         clock, repeats)


#: clocks of `marginal_rate`
CLOCKS = {"wall": time.perf_counter, "cpu": time.process_time}


def marginal_rate(run, q: Query, who: str, clock: str = "wall", repeats: int = 3) -> float | dict[str, float]:
    """Queries per second of run(q[:m]) between m = len(q) / 8 and len(q) (best of `repeats` each, after a
    warm-up call on 64 and on each size), so that fixed costs do not count; seconds of `clock` ("wall" or "cpu": this
    process's CPU seconds, `CLOCKS`), or "both": {"wall": rate, "cpu": rate} read around the same calls (half the
    runs of two measurements). A loaded machine's noise can make the larger batch look no slower: then it measures
    again with twice the repeats, up to twice; NaN when it still does (overheads dominate: use more queries)."""
    if clock not in CLOCKS and clock != "both":
        raise InputError(f"{who} clock: expected one of {', '.join(CLOCKS)} or both, got {clock!r}")
    n = len(q.wi)
    if n < 64:
        raise InputError(f"{who}: expected at least 64 queries, got {n}")
    run(q[:64])  # driver start-up, compilation
    run(q[:n // 8])  # and whatever a new batch size compiles or allocates, at both sizes
    run(q)
    clocks = CLOCKS if clock == "both" else {clock: CLOCKS[clock]}
    rates = dict.fromkeys(clocks, float("nan"))
    for r in (repeats, 2 * repeats, 4 * repeats):
        large = best_times(lambda: run(q), r, clocks)
        small = best_times(lambda: run(q[:n // 8]), r, clocks)
        for name in clocks:
            if large[name] > small[name] and math.isnan(rates[name]):  # this clock's first success
                rates[name] = (n - n // 8) / (large[name] - small[name])
        if not any(math.isnan(x) for x in rates.values()):
            break
    return rates if clock == "both" else rates[clock]


def glsl_run(export: GLSLExport, inputs: dict[str, torch.Tensor], call: str, backend: str | None = "egl",
             width: int = 256, version: str | None = None) -> torch.Tensor:
    """Run `call` (GLSL statements that set `vec4 colour`) once per row of the inputs, with the export's source
    and textures (float16 ones uploaded as RGBA16F; its `images` bound read-only to their image units under GLSL
    4.20 and later) compiled under `version` (a #version line; default `export.fastest_glsl_version()`); each input (N,
    k <= 4) is a vec4 variable of its name (zero-padded). Returns colour (N, 4) float32 on the CPU. One fragment
    per row of an RGBA32F framebuffer `width` wide. By default an OpenGL below 4.2 compiles it under GLSL 3.30."""
    asked = version
    version = export.fastest_glsl_version() if version is None else version
    number = glsl_version_number(version)
    n = len(next(iter(inputs.values())))
    if any(v.shape[0] != n or v.dim() != 2 or v.shape[1] > 4 for v in inputs.values()):
        raise InputError(f"glsl_run inputs: expected (N, k <= 4) tensors with one N, got "
                         f"{ {k: tuple(v.shape) for k, v in inputs.items()} }")
    if n == 0:
        return torch.zeros(0, 4)
    moderngl, ctx = _context(backend)
    try:
        if number > ctx.version_code:
            if asked is not None:
                raise InputError(f"glsl_run: this OpenGL context ({ctx.version_code}) cannot compile {version!r}")
            version, number = GLSL_VERSION, glsl_version_number(GLSL_VERSION)  # an older OpenGL (macOS 4.1)
        images = export.images if number >= glsl_version_number(GLSL_IMAGE_VERSION) else {}
        cols = min(width, n)
        rows = -(-n // cols)

        def upload(values: torch.Tensor, unit: int):
            data = np.zeros((rows * cols, 4), np.float32)
            data[:n, :values.shape[1]] = values.detach().float().cpu().numpy()
            tex = ctx.texture((cols, rows), 4, data.tobytes(), dtype="f4")
            tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
            tex.use(unit)
            return tex

        fragment = _FRAGMENT.format(
            uniforms="\n".join(f"uniform sampler2D {name}_in;" for name in inputs), material=export.source,
            reads="\n".join(f"    vec4 {name} = texelFetch({name}_in, p, 0);" for name in inputs), call=call)
        program = ctx.program(vertex_shader=_VERTEX.replace(GLSL_VERSION, version, 1),
                              fragment_shader=fragment.replace(GLSL_VERSION, version, 1))
        keep = []
        for unit, (name, values) in enumerate(inputs.items()):
            if f"{name}_in" in program:  # unused inputs (uv of a homogeneous export) are compiled away
                keep.append(upload(values, unit))
                program[f"{name}_in"] = unit
        for unit, (name, data) in enumerate(export.textures.items(), start=len(inputs)):
            if name not in program:
                continue
            layers, height, width_, _ = data.shape
            half = data.dtype == np.float16  # RGBA16F (an fp16 export), else RGBA32F
            tex = ctx.texture_array((width_, height, layers), 4,
                                    np.ascontiguousarray(data, np.float16 if half else np.float32).tobytes(),
                                    dtype="f2" if half else "f4")
            tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
            keep.append(tex)
            if name in images:  # its unit is in the source (layout binding)
                tex.bind_to_image(images[name], read=True, write=False)
                continue
            tex.use(unit)
            program[name] = unit
        quad = ctx.buffer(np.array([-1, -1, 1, -1, -1, 1, 1, 1], np.float32).tobytes())
        vao = ctx.vertex_array(program, [(quad, "2f", "position")])
        target = ctx.texture((cols, rows), 4, dtype="f4")
        fbo = ctx.framebuffer(color_attachments=[target])
        fbo.use()
        ctx.viewport = (0, 0, cols, rows)
        vao.render(moderngl.TRIANGLE_STRIP)
        out = np.frombuffer(fbo.read(components=4, dtype="f4"), np.float32).reshape(rows * cols, 4)[:n]
        return torch.from_numpy(out.copy())
    finally:
        ctx.release()


_TRANSLUCENT_CALL = "colour = vec4(neumat_translucent(wi.xyz, x.xyz, wo.xyz), 1.0);"


def neupress_parity_queries(model, n: int, seed: int = 0) -> tuple[Query, torch.Tensor, torch.Tensor]:
    """n random NeuPreSS queries (x uniform in the model's bounding box, wi, wo uniform on the sphere) and the
    model's S_hat (N, 3) and lobe width sigma (N,) there."""
    from ..warp.sphere import sample_uniform_sphere

    g = torch.Generator().manual_seed(seed)
    x = model.box_min + (model.box_max - model.box_min) * torch.rand(n, 3, generator=g)
    wi, wo = (sample_uniform_sphere(torch.rand(n, 2, generator=g)) for _ in range(2))
    q = Query(wi=wi, wo=wo, x=x)
    with torch.no_grad():
        return q, model.eval(q), model.sigma(x, wo)


def neupress_differences(f: torch.Tensor, sigma: torch.Tensor, got_f: torch.Tensor,
                         got_sigma: torch.Tensor) -> dict[str, float]:
    """Largest differences of an export's S_hat (relative to the largest value) and sigma (relative)."""
    return {"translucent": float((got_f - f).abs().max() / f.abs().max().clamp(min=1e-30)),
            "sigma": float(((got_sigma - sigma) / sigma).abs().max())}


def neupress_parity(export: GLSLExport, model, n: int, seed: int = 0, backend: str | None = "egl") -> dict[str, float]:
    """Largest differences of a NeuPreSS export from `model` on n random queries (`neupress_parity_queries`):
    "translucent" relative to the largest value, "sigma" relative."""
    q, f, sigma = neupress_parity_queries(model, n, seed)
    inputs = {"wi": q.wi, "x": q.x, "wo": q.wo}
    g_f = glsl_run(export, inputs, _TRANSLUCENT_CALL, backend)[:, :3]
    g_sigma = glsl_run(export, inputs, "colour = vec4(neumat_sigma(x.xyz, wo.xyz));", backend)[:, 0]
    return neupress_differences(f, sigma, g_f, g_sigma)

