"""Real-Time Neural Appearance Models (Zeltner et al. 2024, Sec. 6.3, Figs. 11-12) on our data: variance of the
neural importance sampler against cosine sampling, the isotropic-lobe ablation and the analytic proxy fitted alone.

    python benchmarks/studies/neural_appearance/neural_appearance_sampler.py                    # 3 texture sets + 1 layered source
    python benchmarks/studies/neural_appearance/neural_appearance_sampler.py --sources Wood092_1K --steps 300 --batch 256 --points 8 --samples 256

Sources as `benchmarks/studies/neural_appearance/neural_appearance_images.py` (`open_source`: SET, coated:SET, smudged:SET at --size texels,
16 footprint samples), "procedural:KIND", a `procedural_texture_set` of --size texels (e.g. "ridges": parallel
grooves whose filtered normals spread along one axis, the anisotropic case of Fig. 11), and "glossy:KIND", the
same with half its roughness and metalness 1 (a glossy metal, whose narrow lobes the normal map moves). Per source, at --steps x --batch (its recipe otherwise):
  "ours"       neural-appearance with the paper's sampler (elliptical, non-centred GGX + tilted cosine lobe);
  "isotropic"  neural-appearance with sampler_lobes="isotropic" (two outputs: diffuse weight and one roughness;
               centred isotropic GGX + untilted cosine lobe; the paper's ablation, after Sztrajman et al. 2021 and
               Fan et al. 2022). Same seed: the sampler is built last and trained on the detached latent, so the
               BRDF and latents come out the same as ours (the table's header prints the largest difference);
  "alone"      the analytic proxy fitted alone: a `ProxySampler` trained by `fit_sampler` (--proxy-steps x --batch,
               point queries, wi uniform) against ours' BRDF, conditioned on the source's texture parameters
               k(x) at uv (`sampling_features`, 8 per SVBRDF, 13 with a coat) instead of the model's latent: the
               stand-alone sampler `benchmarks/studies/neural_appearance/proxy_sampler.py` fits to an SVBRDF, i.e. what one would ship
               for a textured material without the latent;
  "iso refit", "ours refit": the trained isotropic / ours model with its sampler trained anew by `fit_sampler`
               (--proxy-steps x --batch, point queries) on its latent against its final, fixed BRDF: trained
               jointly (the paper's way), the isotropic sampler can collapse to its cosine lobe (see
               benchmarks/studies/neural_appearance/results/neural_appearance_sampler.md), and a refit separates the lobe family from that training dynamic;
  "cosine"     cosine-weighted sampling of the geometric hemisphere.
The learned samplers draw with the defensive 5 % cosine share (`neumat.methods.neural_appearance.proxy_sampler.DEFENSIVE`).

Estimates: one-sample estimates f cos / p (luminance) of the directional albedo of one BRDF, so that only the
sampler differs: "model" rows use ours' f (what the samplers were trained for), "reference" rows the source's
(point value at "fine", its 16-sample Monte Carlo filtered value at "coarse": noisy in f, the same for all
samplers). At --points texture points (fixed uniform uv) x --samples samples each, wi at each --thetas elevation
(azimuth 30 degrees) and each level: "fine" = point queries (finest pyramid level: normal-mapped detail,
non-centred lobes), "coarse" and "far" = isotropic footprints of --coarse and --far texels standard deviation
(coarse levels, LEAN-filtered: anisotropic lobes where the normal map is directional). The log prints, per
level, "f change" = mean |f(level) - f(fine)| / mean f(fine) of ours on cosine-distributed directions: how much
the filtered BRDF differs from the finest one. "rel var" = Var / mean^2 per texture
point (the pixel-wise variance of Fig. 11), averaged over the points where no sampler's estimates are all 0; "gain X" = rel var cosine / rel var X;
"z" the largest |mean X - mean cosine| / standard error over the samplers (unbiased: within a few).
--figure PATH: for the first source, a picture like Fig. 11: per-pixel standard deviation of a 4-sample albedo
estimate (ours' f, wi at 30 degrees, from 64 samples per pixel) over a 48 x 48 grid of texture points, one panel
per sampler (columns) and level (rows: fine, far), magma colour map on one scale (0 to the 99th percentile of
all panels), the mean in each title.
Timing (one thread, 2^15 queries, best of three): microseconds per sample of the whole estimator (lobes,
sample, pdf, and f of ours at the sampled direction; `model.sample` for ours and isotropic, one latent fetch),
and TTUV = mean rel var over the elevations x seconds per sample (the paper's time to unit variance, Fig. 12).
"""
from __future__ import annotations

import argparse
import math
import platform
import time
from dataclasses import replace
from pathlib import Path

import torch

from .neural_appearance import rate
from .neural_appearance_images import open_source, start_run

from neumat.cli.common import print_table
from neumat.color.tonemap import LUMINANCE
from neumat.core.material import Material
from neumat.core.query import Query
from neumat.methods.neural_appearance.proxy_train import fit_sampler
from neumat.fit.method import recipe_for
from neumat.methods.neural_appearance.train import config_for_source
from neumat.fit.trainer import fit
from neumat.reflectance.procedural_texture import procedural_texture_set
from neumat.reflectance.svbrdf import SVBRDF
from neumat.methods.neural_appearance.model import NeuralAppearance
from neumat.methods.neural_appearance.proxy_sampler import ProxySampler, SampledMaterial, defensive_pdf, sample_defensive
from neumat.warp.hemisphere import sample_cosine_hemisphere

SAMPLERS = ("cosine", "alone", "isotropic", "iso refit", "ours", "ours refit")
CHUNK = 1 << 15


class TextureConditioned(Material):
    """`model`'s BRDF with `source`'s texture parameters k(x) as sampling features: the target of the proxy
    fitted alone (no latent)."""

    spatially_varying = True

    def __init__(self, model: Material, source: Material) -> None:
        self.model, self.source, self.name = model, source, "texture-conditioned " + model.name
        self.sampling_feature_dim = int(source.sampling_feature_dim)

    def eval(self, q: Query) -> torch.Tensor:
        return self.model.eval(q)

    def sampling_features(self, q: Query) -> torch.Tensor:
        return self.source.sampling_features(q)


def source_of(spec: str, data: Path, size: int):
    """`open_source(spec)` with 16 footprint samples, or the procedural texture set of "procedural:KIND"."""
    kind, _, name = spec.partition(":")
    if kind in ("procedural", "glossy"):
        textures = procedural_texture_set(name, size, seed=0)
        if kind == "glossy":
            textures = replace(textures, roughness=0.5 * textures.roughness,
                               metalness=torch.ones_like(textures.metalness))
        return SVBRDF(textures, samples=16)
    return open_source(spec, data, size, 16)


def queries(theta: float, uv: torch.Tensor, samples: int, footprint: float | None, texels: int) -> Query:
    """wi at elevation theta (degrees, azimuth 30) for every uv (P, 2) repeated `samples` times (point-major),
    with an isotropic footprint of `footprint` texels standard deviation (None: point queries)."""
    t, p = math.radians(theta), math.radians(30.0)
    n = len(uv) * samples
    wi = torch.tensor([math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)]).expand(n, 3)
    cov = None if footprint is None else (footprint / texels) ** 2 * torch.eye(2).expand(n, 2, 2)
    return Query(wi, uv=uv.repeat_interleave(samples, 0), footprint=cov)


@torch.no_grad()
def estimates(brdf: Material, lobes_fn, q: Query, u: torch.Tensor) -> torch.Tensor:
    """Luminance of f cos / p (N,) with wo from the lobes (defensive mixture) or cosine when lobes_fn is None."""
    out = []
    lum = torch.tensor(LUMINANCE)
    for s in range(0, len(q), CHUNK):
        qc = Query(q.wi[s:s + CHUNK], uv=q.uv[s:s + CHUNK],
                   footprint=None if q.footprint is None else q.footprint[s:s + CHUNK])
        uc = u[s:s + CHUNK]
        if lobes_fn is None:
            wo = sample_cosine_hemisphere(uc)
            out.append((brdf.eval(qc.with_wo(wo)).float() @ lum) * math.pi)
            continue
        lobes = lobes_fn(qc)
        wo = sample_defensive(lobes, qc.wi, uc, check=False)
        pdf = defensive_pdf(lobes, qc.wi, wo, check=False)
        w = wo[:, 2].clamp(min=0) / pdf.clamp(min=1e-30)
        out.append((brdf.eval(qc.with_wo(wo)).float() @ lum) * torch.where(pdf > 0, w, torch.zeros_like(w)))
    return torch.cat(out)


def statistics(est: dict[str, torch.Tensor], points: int) -> dict:
    """Mean per-point rel var of each sampler, and the largest |z| against cosine of the overall means."""
    rel, means, ses = {}, {}, {}
    # a point where some sampler's estimates are all 0 has no relative variance: left out for every sampler
    lit = torch.stack([v.double().view(points, -1).mean(1) > 0 for v in est.values()]).all(0)
    for k, v in est.items():
        v = v.double().view(points, -1)
        rel[k] = float((v.var(1)[lit] / v.mean(1)[lit] ** 2).mean())
        means[k] = float(v.mean())
        ses[k] = float(v.var(1).sum().sqrt() / v.numel() ** 0.5 / points ** 0.5)
    z = max(abs(means[k] - means["cosine"]) / math.hypot(ses[k], ses["cosine"]) for k in est if k != "cosine")
    return {"rel": rel, "albedo": means["cosine"], "z": z}


def figure(path: str, brdf: Material, models: dict, levels: dict, texels: int, grid: int = 48,
           samples: int = 64) -> None:
    """The --figure picture (module docstring)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    c = (torch.arange(grid) + 0.5) / grid
    uv = torch.stack(torch.meshgrid(c, c, indexing="xy"), -1).reshape(-1, 2)
    maps = {}
    for level, footprint in levels.items():
        q = queries(30.0, uv, samples, footprint, texels)
        u = torch.rand(len(q), 2, generator=torch.Generator().manual_seed(17))
        for k in SAMPLERS:
            est = estimates(brdf, None if k == "cosine" else models[k].lobes, q, u).view(grid, grid, samples)
            maps[level, k] = (est.std(-1) / 2).numpy()                          # 4 samples: std / sqrt(4)
    top = float(torch.quantile(torch.cat([torch.from_numpy(m).flatten() for m in maps.values()]), 0.99))
    fig, axes = plt.subplots(len(levels), len(SAMPLERS), figsize=(2.2 * len(SAMPLERS), 2.8 * len(levels)))
    for i, level in enumerate(levels):
        for j, k in enumerate(SAMPLERS):
            ax = axes[i][j]
            ax.imshow(maps[level, k], cmap="magma", vmin=0, vmax=top)
            ax.set_title(f"{level} {k}\nmean {maps[level, k].mean():.3g}", fontsize=8)
            ax.axis("off")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    print(f"written {path}", flush=True)


def train(source, steps: int, batch: int, lobes: str) -> tuple[NeuralAppearance, float]:
    torch.manual_seed(0)
    model = NeuralAppearance(**config_for_source(source), sampler_lobes=lobes)
    t = time.perf_counter()
    fit(model, source, replace(recipe_for(model.name), batch_size=batch), steps=steps, progress=False)
    return model.train(False), time.perf_counter() - t


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sources", default="Wood092_1K,Metal027_1K,Paper001_1K,coated:Wood092_1K")
    ap.add_argument("--size", type=int, default=64)
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument("--batch", type=int, default=1024)
    ap.add_argument("--proxy-steps", type=int, default=None, help="the proxy fitted alone (default: --steps)")
    ap.add_argument("--points", type=int, default=64, help="texture points per cell")
    ap.add_argument("--samples", type=int, default=1024, help="samples per texture point")
    ap.add_argument("--thetas", default="0,30,60,80")
    ap.add_argument("--coarse", type=float, default=4.0, help="footprint std of the coarse level, texels")
    ap.add_argument("--far", type=float, default=16.0, help="footprint std of the far level, texels")
    ap.add_argument("--no-reference", action="store_true", help="model rows only")
    ap.add_argument("--figure", default=None, help="write a Fig. 11-like picture of the first source (docstring)")
    args = ap.parse_args()
    data, commit = start_run()
    print(f"# commit {commit}, {platform.node()}, 1 thread; {args.steps} steps x {args.batch}, {args.size}^2; "
          f"{args.points} points x {args.samples} samples per cell", flush=True)
    thetas = [float(t) for t in args.thetas.split(",")]
    levels = {"fine": None, "coarse": args.coarse, "far": args.far}
    rows, timing = [], []
    for spec in args.sources.split(","):
        source = source_of(spec, data, args.size)
        texels = NeuralAppearance(**config_for_source(source)).cfg.spatial_size
        ours, ours_s = train(source, args.steps, args.batch, "anisotropic")
        iso, iso_s = train(source, args.steps, args.batch, "isotropic")
        proxy_steps = args.proxy_steps or args.steps

        def fitted(material, lobes: str = "anisotropic") -> SampledMaterial:
            torch.manual_seed(0)
            features = int(getattr(material, "sampling_feature_dim", 0))
            sampler = ProxySampler(features=features, lobes=lobes)
            return SampledMaterial(material, fit_sampler(material, sampler, steps=proxy_steps, batch=args.batch,
                                                         progress=False).sampler)

        t = time.perf_counter()
        alone = fitted(TextureConditioned(ours, source))
        alone_s = time.perf_counter() - t
        iso_refit, ours_refit = fitted(iso, "isotropic"), fitted(ours)
        g = torch.Generator().manual_seed(7)
        uv = torch.rand(args.points, 2, generator=g)
        check = queries(45.0, uv, 64, None, texels)
        check = check.with_wo(sample_cosine_hemisphere(torch.rand(len(check), 2, generator=g)))
        with torch.no_grad():
            brdf_diff = float((iso.eval(check) - ours.eval(check)).abs().max() / ours.eval(check).abs().max())
        print(f"{spec}: fit s ours {ours_s:.0f}, isotropic {iso_s:.0f}, alone {alone_s:.0f}; isotropic model's f vs "
              f"ours: largest difference {brdf_diff:.2e} of the largest value", flush=True)
        models = {"ours": ours, "isotropic": iso, "alone": alone, "iso refit": iso_refit, "ours refit": ours_refit}
        if args.figure and spec == args.sources.split(",")[0]:
            figure(args.figure, ours, models, {"fine": None, "far": args.far}, texels)
        with torch.no_grad():
            for name in ("isotropic", "iso refit", "ours"):
                lobes = models[name].lobes(check)
                print(f"  {name} lobes at 45 degrees: w_d mean {float(lobes.w_d.mean()):.3f}, alpha mean "
                      f"{float(lobes.alpha.mean()):.3f}", flush=True)
        brdfs = {"model": ours} if args.no_reference else {"model": ours, "reference": source}
        for level, footprint in levels.items():
            with torch.no_grad():
                fine = ours.eval(check)
                moved = ours.eval(queries(45.0, uv, 64, footprint, texels).with_wo(check.wo))
            print(f"  {level}: f change {float((moved - fine).abs().mean() / fine.abs().mean()):.3f}", flush=True)
            for theta in thetas:
                q = queries(theta, uv, args.samples, footprint, texels)
                u = torch.rand(len(q), 2, generator=torch.Generator().manual_seed(11))
                for brdf_name, brdf in brdfs.items():
                    est = {k: estimates(brdf, None if k == "cosine" else models[k].lobes,
                                        q, u) for k in SAMPLERS}
                    s = statistics(est, args.points)
                    rows.append({"source": spec, "level": level, "theta": theta, "f": brdf_name,
                                 "albedo": s["albedo"], "rel var cosine": s["rel"]["cosine"],
                                 **{f"gain {k}": s["rel"]["cosine"] / s["rel"][k] for k in SAMPLERS[1:]},
                                 "max |z|": s["z"], **{f"rel var {k}": s["rel"][k] for k in SAMPLERS[1:]}})
                print(f"  {level} {theta:.0f}: " + "; ".join(r["f"] + " gain " + ", ".join(
                    f"{k} {r['gain ' + k]:.2f}" for k in SAMPLERS[1:]) + f", z {r['max |z|']:.1f}"
                    for r in rows[-len(brdfs):]), flush=True)
            q = queries(60.0, uv, CHUNK // args.points, footprint, texels)
            u = torch.rand(len(q), 2, generator=torch.Generator().manual_seed(13))
            calls = {"cosine": lambda: ours.eval(q.with_wo(sample_cosine_hemisphere(u))),
                     "alone": lambda: alone.sample(q, u), "isotropic": lambda: iso.sample(q, u),
                     "iso refit": lambda: iso_refit.sample(q, u), "ours": lambda: ours.sample(q, u),
                     "ours refit": lambda: ours_refit.sample(q, u)}
            for k in SAMPLERS:
                us = 1e6 / rate(calls[k], len(q))
                rel = [r[f"rel var {k}"] for r in rows if r["source"] == spec and r["level"] == level
                       and r["f"] == "model"]
                mean_rel = sum(rel) / len(rel)
                timing.append({"source": spec, "level": level, "sampler": k, "us/sample": us,
                               "mean rel var": mean_rel, "TTUV us": mean_rel * us})
    print_table(f"Relative variance (mean over {args.points} texture points of Var/mean^2, {args.samples} samples "
                f"each) of one-sample albedo estimates; gain = rel var cosine / rel var sampler", rows, width=300)
    print_table("Time per sample (one thread, estimator incl. f of ours) and time to unit variance (mean rel var "
                "over the elevations x time)", timing, width=200)


if __name__ == "__main__":
    main()
