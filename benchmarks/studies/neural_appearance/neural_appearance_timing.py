"""Real-Time Neural Appearance Models (Zeltner et al. 2024, Sec. 8.2-8.3, Table 5, Figs. 17-18) at CPU scale: the
cost of shading one path vertex with neural-appearance against the layered reference materials and a
constant-colour material, the memory of the runtime, and the cost as the number of distinct materials grows.

    python benchmarks/studies/neural_appearance/neural_appearance_timing.py                          # shading table, memory, scalability
    python benchmarks/studies/neural_appearance/neural_appearance_timing.py --parts shading --repeats 3 --points 4096   # a smoke run

"shading": a shading point as a path tracer uses the material (the paper's Table 5 measures material shading
inside its path tracer): `material.sample(q, u)`, i.e. one importance-sampled direction, its pdf and the BRDF value
there (for neural-appearance: the filtered latent and the sampler's lobes once, the proxy sample, its pdf, one
decode; `NeuralAppearance.sample`), and, as a second column, `eval` alone. --points shading points per call, wi
cosine-distributed, uv uniform, best of --repeats calls, one thread, all materials in one run (ratios are what
count: the machine is shared). neural-appearance (untrained: the cost does not depend on the weights) reads a
64^2 latent pyramid with an isotropic footprint of about one texel (anisotropic filtering, as the exports' API);
BRDF decoders 2 x 16, 2 x 32 (the default) and 3 x 64, sampler 3 x 32 (Config.hidden x hidden_layers, sampler_*).
The references are the analytic layered materials of `neumat.reflectance.layered` at 64^2 (Wood092_1K and
Metal027_1K from shared/data): "coated SVBRDF" (a tinted clear coat over the texture set), "smudged coat" (coat
roughness from a smudge mask), "conductor + coat" (textured gold under a clear coat), "sheen + coat" (a sheen on a
coated SVBRDF), and the plain SVBRDF; they shade at the point (no footprint: their footprint filtering is Monte Carlo
over texture positions, which a renderer would replace by mip-mapped textures), with their own samplers. The
constant-colour material is a Lambert (the paper's baseline "pure path tracing cost"); "minus constant" subtracts
its time (torch's per-call overheads) from every row. With --glsl, the fp16 GLSL export's shading
(neumat_lobes once, neumat_sample, neumat_pdf, neumat_eval at the sampled direction) on this OpenGL (llvmpipe: a
CPU rasteriser, SIMD over fragments) against a constant-colour shader (cosine sample, its pdf, a constant), as the
marginal rate of `neumat.testing.parity.marginal_rate` (context, compilation and uploads do not count).

"memory": the latent pyramid of a 4096^2 tile at fp16 (8 channels) and the network weights per decoder size at
fp16, from the models' own parameter counts, beside the paper's figures (256 MB per 4k tile; 37 kB for 3 x 64 and
9.3 kB for 2 x 16).

"scaling" (Fig. 18): --points shading points, each assigned one of K distinct neural materials (K = 1, 2, 4, 8, 16,
uniformly at random; 2 x 32 decoders, different random weights and latents), shaded "grouped" (the points sorted by
material, one batched call per material: the analogue of the paper's shader execution reordering) or "arrival
order" (the first --arrival-points points taken in arrival order in groups of 32, a GPU warp, each group making one
call per material it contains: what a SIMD machine does with divergent materials and no reordering; best of 2).
Time per shading point.
"""
from __future__ import annotations

import argparse
import os
import platform
from dataclasses import replace
from pathlib import Path

import torch

from .neural_appearance_images import open_source, start_run

from neumat.cli.common import print_table
from neumat.core.query import Query
from neumat.export.glsl import export_glsl
from neumat.methods.neural_appearance.model import NeuralAppearance
from neumat.reflectance.analytic import Lambert
from neumat.reflectance.conductor_base import TexturedConductor
from neumat.reflectance.layered import Coat, LayeredMaterial, Sheen
from neumat.reflectance.smudge_map import smudge_map
from neumat.testing.parity import glsl_run, marginal_rate, opengl_available
from neumat.testing.timing import best_time
from neumat.warp.hemisphere import sample_cosine_hemisphere

#: the paper's decoder sizes (hidden neurons, hidden layers); the sampler is 3 x 32 for all
SIZES = {"2x16": (16, 2), "2x32": (32, 2), "3x64": (64, 3)}
SIZE = 64
#: the paper's figures (Sec. 8.3, "Memory usage")
PAPER_LATENT_4K = 256 * 2 ** 20
PAPER_WEIGHTS = {"2x16": 9.3e3, "3x64": 37e3}
#: the constant-colour baseline shader (GLSL): a cosine sample, its pdf and a constant value
CONSTANT_GLSL = """
    float r = sqrt(u.x), phi = 6.2831853 * u.y;
    vec3 wo = vec3(r * cos(phi), r * sin(phi), sqrt(max(0.0, 1.0 - u.x)));
    colour = vec4(vec3(0.5 / 3.14159265), wo.z / 3.14159265);"""
NEURAL_GLSL = """
    NeumatLobes l = neumat_lobes(wi.xyz, uv.xy, mat2(f.x, f.y, f.y, f.z));
    vec3 wo = neumat_sample(l, u.xy);
    colour = vec4(neumat_eval(l, wo), neumat_pdf(l, wo));"""


def queries(n: int, seed: int = 3) -> tuple[Query, Query, torch.Tensor]:
    """(footprint query, point query, u (n, 2)): cosine-distributed wi and wo, uniform uv, an isotropic footprint
    of one 64^2 texel (variance (1/64)^2)."""
    g = torch.Generator().manual_seed(seed)
    wi = sample_cosine_hemisphere(torch.rand(n, 2, generator=g))
    wo = sample_cosine_hemisphere(torch.rand(n, 2, generator=g))
    uv, u = torch.rand(n, 2, generator=g), torch.rand(n, 2, generator=g)
    footprint = torch.eye(2).expand(n, 2, 2) / SIZE ** 2
    return Query(wi, wo, uv=uv, footprint=footprint.contiguous()), Query(wi, wo, uv=uv), u


def neural(hidden: int, layers: int, seed: int = 0) -> NeuralAppearance:
    torch.manual_seed(seed)
    return NeuralAppearance(spatial_size=SIZE, hidden=hidden, hidden_layers=layers).runtime().train(False)


def references(data: Path) -> dict:
    """The layered reference materials of the module docstring, at SIZE^2, one footprint sample (unused: they
    shade at the point)."""
    wood = open_source("Wood092_1K", data, SIZE, 1)
    coat = Coat(roughness=0.05, eta=1.5, tint=(0.92, 0.85, 0.7))
    smudge = Coat(roughness=0.03 + 0.27 * smudge_map(SIZE, seed=1), eta=1.5)
    gold = TexturedConductor("gold", roughness=0.05 + 0.3 * smudge_map(SIZE, seed=2), samples=1)
    return {"SVBRDF (Wood092)": wood,
            "coated SVBRDF": LayeredMaterial(wood, [coat], samples=1),
            "smudged coat over SVBRDF (Metal027)": open_source("smudged:Metal027_1K", data, SIZE, 1),
            "conductor + coat": LayeredMaterial(gold, [smudge], samples=1),
            "sheen + coat over SVBRDF": LayeredMaterial(wood, [coat], samples=1,
                                                        sheen=Sheen(color=(0.9, 0.9, 1.0), roughness=0.4))}


def shading_rows(data: Path, args) -> list[dict]:
    """The shading table (module docstring)."""
    n = args.points
    fq, pq, u = queries(n)
    materials = {f"neural-appearance {k}": (neural(*v), fq) for k, v in SIZES.items()}
    materials |= {name: (m, pq) for name, m in references(data).items()}
    materials["constant colour (Lambert)"] = (Lambert((0.5, 0.5, 0.5)), pq)
    rows = []
    for name, (m, q) in materials.items():
        shade = best_time(lambda: m.sample(q, u), args.repeats) / n
        ev = best_time(lambda: m.eval(q), args.repeats) / n
        rows.append({"material": name, "shade us/pt": shade * 1e6, "eval us/pt": ev * 1e6})
        print(rows[-1], flush=True)
    const = rows[-1]
    for r in rows:
        r["shade minus constant"] = r["shade us/pt"] - const["shade us/pt"]
    neural_2x32 = rows[1]["shade minus constant"]
    for r in rows:
        r["x 2x32 (minus constant)"] = r["shade minus constant"] / neural_2x32
    return rows


def glsl_rows(args) -> list[dict]:
    """--glsl: shading rates of the fp16 exports and of a constant shader on llvmpipe (module docstring)."""
    if not opengl_available():
        print("# --glsl: no OpenGL 3.3 context here; skipped", flush=True)
        return []
    fq, _, u = queries(args.glsl_points)
    fp = fq.footprint
    inputs = {"wi": fq.wi, "uv": fq.uv, "f": torch.stack([fp[:, 0, 0], fp[:, 0, 1], fp[:, 1, 1]], -1), "u": u}
    rows = []
    for name, (hidden, layers) in SIZES.items():
        export = export_glsl(neural(hidden, layers))
        rate = marginal_rate(lambda q: glsl_run(export, {k: v[:len(q.wi)] for k, v in inputs.items()}, NEURAL_GLSL),
                             fq, "glsl shading")
        rows.append({"shader": f"neural-appearance {name} (fp16 export)", "us/pt": 1e6 / rate})
        print(rows[-1], flush=True)
    empty = replace(export, source="", textures={})
    rate = marginal_rate(lambda q: glsl_run(empty, {"u": u[:len(q.wi)]}, CONSTANT_GLSL), fq, "glsl constant")
    rows.append({"shader": "constant colour", "us/pt": 1e6 / rate})
    for r in rows:
        r["minus constant"] = r["us/pt"] - rows[-1]["us/pt"]
    return rows


def memory_rows() -> list[dict]:
    """Latent bytes of a 4k tile and network weight bytes per decoder size, at fp16 (module docstring)."""
    m = neural(32, 2)
    per_texel = m.cfg.spatial_channels * 2
    finest = 4096 ** 2 * per_texel
    pyramid = sum((4096 >> level) ** 2 for level in range(13)) * per_texel
    rows = [{"what": "latent texture, 4096^2, 8 channels, fp16: finest level", "ours (bytes)": finest,
             "paper (bytes)": PAPER_LATENT_4K},
            {"what": "latent texture, 4096^2: whole mip pyramid (13 levels)", "ours (bytes)": pyramid,
             "paper (bytes)": float("nan")}]
    for name, (hidden, layers) in SIZES.items():
        m = neural(hidden, layers)
        counts = {g: sum(p.numel() for k, p in m.named_parameters() if k.startswith(g))
                  for g in ("frame.", "mlp.", "sampler.")}
        rows.append({"what": f"weights {name}: BRDF decoder {counts['mlp.']} + frames {counts['frame.']} + sampler "
                             f"{counts['sampler.']} values, fp16",
                     "ours (bytes)": 2 * sum(counts.values()), "paper (bytes)": PAPER_WEIGHTS.get(name, float("nan"))})
    return rows


def scaling_rows(args) -> list[dict]:
    """Fig. 18 at CPU scale (module docstring)."""
    n = args.points
    fq, _, u = queries(n)
    models = [neural(32, 2, seed=k) for k in range(max(args.materials))]
    g = torch.Generator().manual_seed(4)
    rows = []
    for count in args.materials:
        ids = torch.randint(count, (n,), generator=g)

        def grouped():
            order = torch.argsort(ids, stable=True)
            sorted_ids = ids[order]
            for k in range(count):
                idx = order[sorted_ids == k]
                models[k].sample(fq[idx], u[idx])

        def arrival(warp: int = 32):
            for start in range(0, args.arrival_points, warp):
                chunk = ids[start:start + warp]
                for k in chunk.unique().tolist():
                    idx = start + torch.nonzero(chunk == k)[:, 0]
                    models[k].sample(fq[idx], u[idx])

        rows.append({"materials": count, "grouped us/pt": best_time(grouped, args.repeats) / n * 1e6,
                     "arrival order (32-wide) us/pt": best_time(arrival, 2) / args.arrival_points * 1e6,
                     "calls per 32 points (arrival)": float(sum(len(ids[s:s + 32].unique())
                                                                for s in range(0, n, 32))) / (n / 32)})
        print(rows[-1], flush=True)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--parts", default="shading,memory,scaling")
    ap.add_argument("--points", type=int, default=1 << 14)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--glsl", action="store_true", help="also time the fp16 GLSL export on llvmpipe")
    ap.add_argument("--glsl-points", type=int, default=1 << 16)
    ap.add_argument("--arrival-points", type=int, default=2048, help="points of the arrival-order runs (slow)")
    ap.add_argument("--materials", type=lambda s: [int(x) for x in s.split(",")], default=[1, 2, 4, 8, 16])
    args = ap.parse_args()
    data, commit = start_run()
    print(f"# commit {commit}, {platform.node()}, {platform.processor() or platform.machine()}, 1 thread, load "
          f"{os.getloadavg()[0]:.2f}; {args.points} points per call, best of {args.repeats}", flush=True)
    parts = args.parts.split(",")
    if "shading" in parts:
        print_table("shading cost per point (sample: direction + pdf + BRDF value)", shading_rows(data, args), 220)
        if args.glsl:
            print_table("fp16 GLSL export on llvmpipe (lobes once, sample, pdf, eval)", glsl_rows(args), 220)
    if "memory" in parts:
        print_table("memory at fp16", memory_rows(), 220)
    if "scaling" in parts:
        print_table("shading cost per point with K distinct neural materials (2 x 32)", scaling_rows(args), 220)
    print(f"# load at the end {os.getloadavg()[0]:.2f}", flush=True)


if __name__ == "__main__":
    main()
