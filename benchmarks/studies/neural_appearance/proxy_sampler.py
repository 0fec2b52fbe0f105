"""Neural importance sampling (the two-lobe proxy of Real-Time Neural Appearance Models driven by an MLP of wi)
against cosine sampling and each material's own sampler.

    python benchmarks/studies/neural_appearance/proxy_sampler.py                       # analytic materials + the shared RGL BRDFs
    python benchmarks/studies/neural_appearance/proxy_sampler.py --materials "ggx:roughness=0.1" path/to/model.nmat --steps 1000
    python benchmarks/studies/neural_appearance/proxy_sampler.py --render          # also benchmarks/studies/neural_appearance/results/proxy_sampler_render_ggx.png

For every material: fit a `ProxySampler` (`fit_sampler`, --steps x --batch; on an SVBRDF conditioned on its
texture parameters, and estimates taken at a uniform random uv per sample), then at each incident elevation
estimate the luminance albedo with --samples one-sample estimates f cos / p from cosine sampling, from the
material's own sampler (when it has one) and from the learned proxy. "rel var" is Var / mean^2 of the
estimates (lower is better; the efficiency gain of A over B is rel var B / rel var A at equal sample counts).
"albedo" is the proxy's estimate, "albedo ref" the reference (own sampler, else cosine) estimate: the
proxy is unbiased when they agree within a few standard errors ("z" = difference / combined standard error).

--render: a sphere (a plane for a spatially varying material) of each --render-material under the shared
studio environment map, direct light with MIS at --render-spp, its material strategy drawing from cosine
sampling (what the renderer does for a material that cannot sample, e.g. most learned models), from the
learned proxy, and from the material's own sampler if it has one; the reference is the same estimator at 64x
the samples with the material's own sampler (else the proxy); PSNR and FLIP at the reference's exposure.
"""
from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import torch
from neumat.cli.common import print_table
from neumat.core.material import Material
from neumat.core.query import Query
from neumat.catalog.open_material import open_material
from neumat.io.shared_data import shared_data_dir
from neumat.color.tonemap import LUMINANCE
from neumat.methods.neural_appearance.proxy_train import fit_sampler
from neumat.methods.neural_appearance.proxy_sampler import SampledMaterial
from neumat.warp.hemisphere import sample_cosine_hemisphere

ANALYTIC = ["ggx:roughness=0.05", "ggx:roughness=0.15", "ggx:roughness=0.4", "ggx:alpha_x=0.08,alpha_y=0.4",
            "plastic:diffuse=0.1/0.3/0.8,roughness=0.1,eta=1.5",
            "principled:base_color=0.9/0.6/0.2,metallic=1,roughness=0.4,anisotropy=0.5"]


def estimates(material, theta: float, n: int, how: str, seed: int = 1) -> torch.Tensor:
    """n one-sample estimates (luminance of f cos / p) of the albedo at elevation theta (degrees), azimuth 30;
    on a spatially varying material at a uniform random uv per sample (the texture's mean albedo)."""
    t, p = math.radians(theta), math.radians(30.0)
    wi = torch.tensor([math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)]).expand(n, 3)
    u = torch.rand(n, 4, generator=torch.Generator().manual_seed(seed))
    q = Query(wi, uv=u[:, 2:] if getattr(material, "spatially_varying", False) else None)
    lum = torch.tensor(LUMINANCE)
    with torch.no_grad():
        if how == "cosine":
            return (material.eval(q.with_wo(sample_cosine_hemisphere(u[:, :2]))).float() @ lum) * math.pi
        return material.sample(q, u[:, :2]).weight.float() @ lum


class WithoutSampler(Material):
    """`material` evaluated as is but with no sampler of its own (as most learned models)."""

    def __init__(self, material: Material) -> None:
        self.material, self.name = material, material.name

    def eval(self, q: Query) -> torch.Tensor:
        return self.material.eval(q)


def render_figure(spec: str, steps: int, batch: int, spp: int, resolution: int) -> list[dict]:
    """Write benchmarks/results/proxy_sampler_render_<name>.png (module docstring); one row per sampler."""
    from neumat.io.images import write_image_ldr
    from neumat.metrics.image import image_metrics
    from neumat.render.render import render
    from neumat.viz.compare import compare_image

    data = shared_data_dir()
    env = data / "envmap" / "studio_small_03_1k.hdr" if data is not None else None
    if env is None or not env.is_file():
        raise SystemExit("--render needs shared/data/envmap/studio_small_03_1k.hdr (set NEUMAT_SHARED_DATA)")
    material = open_material(spec)
    torch.manual_seed(0)
    sampled = SampledMaterial(material, fit_sampler(material, steps=steps, batch=batch, progress=False).sampler)
    own = getattr(material, "can_sample", False)
    scene = "plane,uv_scale=2" if getattr(material, "spatially_varying", False) else "sphere"
    light = f"env:{env}"
    ref = render(material if own else sampled, scene, light, spp=64 * spp, resolution=resolution, seed=1)
    exposure = math.log2(0.9 / max(torch.quantile(ref @ torch.tensor(LUMINANCE), 0.99).item(), 1e-8))
    images, metrics, rows = {}, {}, []
    samplers = [("cosine sampling (no sampler)", WithoutSampler(material)), ("learned proxy", sampled)]
    for name, m in samplers + ([("own sampler", material)] if own else []):
        t = time.perf_counter()
        images[name] = render(m, scene, light, spp=spp, resolution=resolution, seed=2)
        seconds = time.perf_counter() - t
        mt = image_metrics(ref, images[name], exposure=exposure)
        metrics[name] = {"PSNR": mt["psnr"], "FLIP": mt["flip"]}
        rows.append({"material": spec, "sampler": name, "spp": spp, "PSNR": mt["psnr"], "FLIP": mt["flip"],
                     "render s": seconds})
    stem = (Path(spec).stem if Path(spec).exists() else spec.split(":")[0]).replace(".", "_")
    out = Path(__file__).parent / "results" / f"proxy_sampler_render_{stem}.png"
    out.parent.mkdir(parents=True, exist_ok=True)
    write_image_ldr(out, compare_image(ref, images, metrics=metrics, exposure=exposure))
    print(f"written {out}")
    return rows


def default_materials() -> list[str]:
    """The analytic set, the shared RGL BRDFs and two shared PBR texture sets (SVBRDFs) when present."""
    data = shared_data_dir()
    rgl = sorted(str(p) for p in (data / "rgl").glob("*.bsdf")) if data is not None else []
    svbrdf = [str(data / "svbrdf" / n) for n in ("Metal027_1K", "Leather05_1K_partial")
              if (data / "svbrdf" / n).is_dir()] if data is not None else []
    if not rgl:
        print("no shared RGL BRDFs found (set NEUMAT_SHARED_DATA or put shared/ beside the checkout): analytic only")
    return ANALYTIC + rgl + svbrdf


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--materials", nargs="*", default=None, help="specs or files (default: analytic + shared RGL)")
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument("--batch", type=int, default=4096)
    ap.add_argument("--samples", type=int, default=200_000)
    ap.add_argument("--thetas", default="0,30,60,80", help="incident elevations, degrees")
    ap.add_argument("--render", action="store_true", help="also render the comparison picture (module docstring)")
    ap.add_argument("--render-material", nargs="*", default=["ggx:roughness=0.1"], help="specs or files")
    ap.add_argument("--render-spp", type=int, default=4)
    ap.add_argument("--render-size", type=int, default=160)
    ap.add_argument("--no-table", action="store_true", help="skip the variance table")
    args = ap.parse_args()
    if args.render:
        rows = [r for spec in args.render_material
                for r in render_figure(spec, args.steps, args.batch, args.render_spp, args.render_size)]
        print_table("Renders under studio_small_03: direct light, MIS, material strategy from each sampler", rows,
                    width=250)
    if args.no_table:
        return
    thetas = [float(t) for t in args.thetas.split(",")]
    rows = []
    for spec in args.materials or default_materials():
        material = open_material(spec)
        name = Path(spec).name if Path(spec).exists() else spec
        torch.manual_seed(0)
        t = time.perf_counter()
        fit = fit_sampler(material, steps=args.steps, batch=args.batch, progress=False)
        fit_s = time.perf_counter() - t
        sampled = SampledMaterial(material, fit.sampler)
        own = getattr(material, "can_sample", False)
        for theta in thetas:
            est = {"cosine": estimates(material, theta, args.samples, "cosine"),
                   "proxy": estimates(sampled, theta, args.samples, "proxy", seed=2)}
            if own:
                est["own"] = estimates(material, theta, args.samples, "own", seed=3)
            rel = {k: (v.var() / v.mean() ** 2).item() for k, v in est.items()}
            ref = est["own" if own else "cosine"]
            se = math.hypot(est["proxy"].std().item(), ref.std().item()) / math.sqrt(args.samples)
            rows.append({"material": name, "theta": theta, "rel var cosine": rel["cosine"],
                         "rel var own": rel.get("own", float("nan")), "rel var proxy": rel["proxy"],
                         "gain vs cosine": rel["cosine"] / rel["proxy"],
                         "gain vs own": rel["own"] / rel["proxy"] if own else float("nan"),
                         "albedo": est["proxy"].mean().item(), "albedo ref": ref.mean().item(),
                         "z": (est["proxy"].mean() - ref.mean()).item() / max(se, 1e-30),
                         "fit s": fit_s})
    print_table(f"Learned proxy sampler vs cosine and own sampling ({args.steps} x {args.batch} fit, "
                f"{args.samples} samples per cell, {torch.get_num_threads()} threads; sampler MLP "
                f"{fit.sampler.flops()} FLOPs, {sum(p.numel() for p in fit.sampler.parameters())} parameters)", rows, width=250)


if __name__ == "__main__":
    main()
