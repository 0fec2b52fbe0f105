"""SH PRT of a NeuPreSS model (Sec. 4.3) on a mesh: where the precompute's time goes, the error of the CLI's
bin counts against the paper's, the full precompute's time and storage, and images of the table against the network
and the path-traced reference.

    python benchmarks/studies/neupress/neupress_prt.py --model bunny.nmat --observations bunny.npz   # a model of the 35k bunny

1. Profile: evaluations per second of the precompute's inner loop, the generic path (`eval(Query)` of repeated
   queries, as before) and the separable NeuPreSS path (Fourier features by angle addition), with the share of
   each stage (pair encoding, feature combination, MLP, projection) on --profile-pairs (vertex, view) pairs.
2. Bin counts, on --subset random vertices: tables at the paper's 16 x 64 view bins x 1024 light directions and at
   cheaper counts and bfloat16 (the CLI's default FAST_VIEW_BINS x FAST_LIGHT_SAMPLES in FAST_PRECISION among them). Errors against the paper's
   table, relative RMS over the subset: of a_lm (interpolated over the view bins at --directions random view
   directions above each vertex's horizon), and of the radiance under the environment (Eq. 11) at the same
   directions and at the camera's view direction of each vertex (what an image shows there). The paper's table
   against the network's Eq. 5 (a 4096-direction Gauss rule) gives the SH truncation error for scale.
3. The full table at the CLI's counts over every vertex of the object's mesh: seconds, vertices, fp16 storage.
4. Images (--resolution^2, subsurface only, the forest map downsampled to 128 x 64): the table (--spp), the network
   (Eq. 5, environment importance sampling, --model-spp, twice with different seeds: its Monte Carlo noise), and
   the path-traced reference (--reference-spp, twice with different seeds: its noise floor); MSE, FLIP, SSIM.
torch runs on --threads threads.
"""
from __future__ import annotations

import argparse
import json
import math
import platform
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import torch

from neumat.catalog.modelfile import load_model
from neumat.cli.common import print_table
from neumat.core.config import config_from_dict
from neumat.core.frames import frame_from_normal
from neumat.core.query import Query
from neumat.fit.translucent_observations import Observations
from neumat.io.images import write_image_ldr
from neumat.io.shared_data import shared_data_dir
from neumat.metrics.image import image_metrics
from neumat.methods.neupress.prt import (FAST_LIGHT_SAMPLES, FAST_PRECISION, FAST_VIEW_BINS, PRTConfig, SHPRT,
                                        _QueryTransport, _SeparableNeuPreSS, sphere_quadrature)
from neumat.nn.spherical_harmonics import real_sh
from neumat.reflectance.translucent import TranslucentConfig, TranslucentObject
from neumat.render.envmaps import downsample_envmap, read_envmap
from neumat.render.lights import EnvironmentMap
from neumat.render.mesh import MeshIntersector, object_mesh, vertex_normals
from neumat.render.translucent import _pixel_rays, orbit_camera, render_translucent, render_translucent_reference
from neumat.render.translucent_prt import render_prt
from neumat.testing.timing import best_time
from neumat.viz.compare import compare_image

PAPER = (16, 64, 1024, "fp32")
FAST = (*FAST_VIEW_BINS, FAST_LIGHT_SAMPLES, FAST_PRECISION)
CHEAPER = [FAST, (8, 16, 32, "fp32"), (8, 16, 64, "bf16"), (8, 16, 64, "fp32"), (4, 8, 32, "bf16"),
           (16, 32, 64, "bf16"), (8, 16, 256, "bf16")]


def _config(counts: tuple, batch_size: int = 16384) -> PRTConfig:
    """PRTConfig of (view_theta, view_phi, light_samples, precision)."""
    return PRTConfig(view_theta=counts[0], view_phi=counts[1], light_samples=counts[2], precision=counts[3],
                     batch_size=batch_size)


def profile(model, pairs: int, lights: int) -> list[dict]:
    """Evaluations per second of both evaluation paths on `pairs` random (x, wo) pairs x the Gauss rule of `lights`,
    and the shares of their stages: the Fourier features (per query: encoding, G v, cos, sin; separable: the
    pairs' encodings and the angle-addition combination), the MLP and the projection (Eq. 10, one GEMM)."""
    g = torch.Generator().manual_seed(0)
    x = torch.rand(pairs, 3, generator=g) * (model.box_max - model.box_min) + model.box_min
    wo = torch.nn.functional.normalize(torch.randn(pairs, 3, generator=g), dim=-1)
    wi = sphere_quadrature(lights)[0].float()
    m = len(wi)
    basis = real_sh(wi.double(), 2).float()
    rows = []
    with torch.no_grad():
        for name, tr in (("eval(Query) of repeated queries", _QueryTransport(model, wi)),
                         ("separable NeuPreSS (angle addition)", _SeparableNeuPreSS(model, wi))):
            val = tr(x, wo, wo)
            total = best_time(lambda: torch.matmul(tr(x, wo, wo).transpose(1, 2), basis))
            proj = best_time(lambda: torch.matmul(val.transpose(1, 2), basis))
            if isinstance(tr, _QueryTransport):
                q = Query(wi=wi.repeat(pairs, 1), wo=wo.repeat_interleave(m, 0), x=x.repeat_interleave(m, 0))
                feats = lambda: model.appearance_features(torch.cat(  # noqa: E731
                    [model._direction(q.wi), model._direction(q.wo), model._position(q.x)], -1))
            else:
                def feats():
                    a = 2 * math.pi * (model._direction(wo) @ tr.g_wo + model._position(x) @ tr.g_x)
                    cp, sp = torch.cos(a)[:, None], torch.sin(a)[:, None]
                    f = a.shape[1]
                    out = torch.empty(pairs, m, 2 * f)
                    torch.mul(cp, tr.cos_l, out=out[..., :f])
                    out[..., :f].sub_(sp * tr.sin_l)
                    torch.mul(sp, tr.cos_l, out=out[..., f:])
                    out[..., f:].add_(cp * tr.sin_l)
                    return out.reshape(-1, 2 * f)
            feature = feats()
            t_feat = best_time(feats)
            t_mlp = best_time(lambda: model.appearance(feature))
            rows.append({"path": name, "evaluations/s": round(pairs * m / total),
                         "features share": round(t_feat / total, 3), "MLP share": round(t_mlp / total, 3),
                         "projection share": round(proj / total, 3),
                         "MLP GFLOP/s": round(model.appearance.flops() * pairs * m / t_mlp / 1e9, 1)})
    return rows


def radiance_env(model, x, wo, env, samples=4096):
    """Eq. 5 of the network at (x, wo) (N, 3) under `env` by a Gauss rule (float64 sums)."""
    d, w = sphere_quadrature(samples)
    lw = env.eval(d.float()).double() * w[:, None]
    out = []
    with torch.no_grad():
        for xi, oi in zip(x, wo):
            s = model.eval(Query(wi=d.float(), wo=oi[None].expand(len(d), 3), x=xi[None].expand(len(d), 3)))
            out.append((s.double() * lw).sum(0))
    return torch.stack(out)


def rel_rms(a, b):
    return float(((a.double() - b.double()) ** 2).mean().sqrt() / (b.double() ** 2).mean().sqrt())


def bin_study(model, points, normals, env, camera_origin, subset: int, directions: int,
              paper: tuple = PAPER) -> list[dict]:
    g = torch.Generator().manual_seed(1)
    cam = torch.nn.functional.normalize(torch.as_tensor(camera_origin, dtype=torch.float32) - points, dim=-1)
    facing = ((cam * normals).sum(-1) > 0.05).nonzero()[:, 0]  # vertices facing the camera
    idx = facing[torch.randperm(len(facing), generator=g)[:subset]]
    pts, nrm, cam = points[idx], normals[idx], cam[idx]
    subset = len(idx)
    # random view directions above each vertex's horizon, and the camera's
    u = torch.rand(subset, directions, 2, generator=g, dtype=torch.float64)
    cos_t, phi = u[..., 0], 2 * math.pi * u[..., 1]
    sin_t = (1 - cos_t ** 2).sqrt()
    loc = torch.stack([sin_t * phi.cos(), sin_t * phi.sin(), cos_t], -1).float()
    t, b = frame_from_normal(nrm)
    wo = (loc[..., :1] * t[:, None] + loc[..., 1:2] * b[:, None] + loc[..., 2:] * nrm[:, None])
    wo = torch.nn.functional.normalize(wo, dim=-1).reshape(-1, 3)
    vi = torch.arange(subset).repeat_interleave(directions)
    tables, seconds, rows = {}, {}, []
    for counts in [paper, *CHEAPER]:
        t0 = time.perf_counter()
        tables[counts] = SHPRT.from_material(model, pts, nrm, _config(counts))
        seconds[counts] = time.perf_counter() - t0
    light = tables[paper].light_coefficients(env)
    ref = tables[paper]
    a_ref = ref.coefficients_at(vi, wo)[0]
    l_ref, c_ref = ref.radiance(vi, wo, light), ref.radiance(torch.arange(subset), cam, light)
    truth = radiance_env(model, pts, cam, env)
    for counts, tab in tables.items():
        lights = sphere_quadrature(counts[2])[1].shape[0]
        rows.append({"view bins x lights": f"{counts[0]}x{counts[1]} x {lights} {counts[3]}",
                     "evaluations per vertex": counts[0] * counts[1] * lights,
                     "seconds per vertex": round(seconds[counts] / subset, 4),
                     "fp16 bytes per vertex": tab.size_bytes() // subset,
                     "a_lm error": rel_rms(tab.coefficients_at(vi, wo)[0], a_ref),
                     "radiance error": rel_rms(tab.radiance(vi, wo, light), l_ref),
                     "camera-view radiance error": rel_rms(tab.radiance(torch.arange(subset), cam, light),
                                                           c_ref),
                     "camera-view error against Eq. 5": rel_rms(tab.radiance(torch.arange(subset), cam,
                                                                             light), truth)})
    return rows


def visible_table(model, points, normals, faces, camera, resolution: int, spp: int) -> tuple[SHPRT, float]:
    """The CLI-count table over all vertices with coefficients only at those of the triangles the camera samples
    of `render_prt` (seed 0) hit, and the seconds of that precompute."""
    o, d = _pixel_rays(camera, resolution, spp, torch.Generator().manual_seed(0))
    hit, face, _ = MeshIntersector(points, faces).intersect(o, d)
    needed = faces[face].unique()
    cfg = _config(FAST)
    t = time.perf_counter()
    part = SHPRT.from_material(model, points[needed], normals[needed], cfg, progress=True)
    seconds = time.perf_counter() - t
    coeffs = torch.zeros(points.shape[0], *part.coefficients.shape[1:])
    coeffs[needed] = part.coefficients
    return SHPRT(coeffs, points, normals, cfg, faces=faces), seconds


def scores(test, ref) -> dict:
    s = image_metrics(ref.numpy(), test.numpy(), tonemap="aces")
    return {"MSE": float(((test - ref) ** 2).mean()), "FLIP": s["flip"], "SSIM": s["ssim"]}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--model", type=Path, required=True)
    p.add_argument("--observations", type=Path, required=True)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--profile-pairs", type=int, default=256)
    p.add_argument("--subset", type=int, default=16)
    p.add_argument("--directions", type=int, default=64)
    p.add_argument("--paper", default="16x64x1024", help="the counts the others are compared with")
    p.add_argument("--resolution", type=int, default=64)
    p.add_argument("--spp", type=int, default=4)
    p.add_argument("--model-spp", type=int, default=512)
    p.add_argument("--reference-spp", type=int, default=256)
    p.add_argument("--stages", default="profile,bins,full,images")
    p.add_argument("--table", type=Path, default=Path("/tmp/neupress_prt_bench.prt"),
                   help="the full table: written by the full stage, read by the images stage")
    p.add_argument("--json", type=Path, default=Path("benchmarks/results/neupress_prt.json"))
    p.add_argument("--image-out", type=Path, default=Path("benchmarks/studies/neupress/results/neupress_prt.png"))
    a = p.parse_args()
    torch.set_num_threads(a.threads)
    stages = a.stages.split(",")
    results = json.loads(a.json.read_text()) if a.json.is_file() else {}
    results["machine"] = (f"{platform.processor() or platform.machine()}, {torch.get_num_threads()} torch threads, "
                          f"torch {torch.__version__}, load average {Path('/proc/loadavg').read_text().split()[0]} "
                          f"at the start")
    results.setdefault("commands", {})
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()

    model = load_model(a.model).eval()
    source = Observations.load_source(a.observations)
    obj = TranslucentObject(config_from_dict(TranslucentConfig, source["object"]), spp=1)
    env = EnvironmentMap(downsample_envmap(read_envmap(shared_data_dir() / "envmap" / "forest_slope_1k.hdr"), 128))
    camera = orbit_camera(obj, a.resolution)
    vertices, faces = object_mesh(obj)
    points, normals = vertices.float(), vertex_normals(vertices, faces).float()

    def record(stage, value):
        results[stage] = value
        results["commands"][stage] = f"python {' '.join(sys.argv)}  (commit {commit})"
        a.json.write_text(json.dumps(results, indent=1))

    if "profile" in stages:
        rows = profile(model, a.profile_pairs, 64)
        print_table(f"Precompute inner loop, {a.profile_pairs} (vertex, view) pairs x 60 lights", rows, width=200)
        record("profile", rows)
    if "bins" in stages:
        eye = camera.rays(torch.tensor([[a.resolution / 2, a.resolution / 2]])).o[0]
        paper = (*(int(v) for v in a.paper.split("x")), "fp32")
        rows = bin_study(model, points, normals, env, eye, a.subset, a.directions, paper)
        print_table(f"Bin counts on {a.subset} vertices, errors against {a.paper}", rows,
                    width=220)
        record("bins", rows)
    if "full" in stages:
        cfg = _config(FAST)
        t = time.perf_counter()
        table = SHPRT.from_material(model, points, normals, cfg, progress=True, faces=faces)
        seconds = time.perf_counter() - t
        table.save(a.table)
        row = {"vertices": table.num_vertices, "view bins": f"{cfg.view_theta}x{cfg.view_phi}",
               "light directions": sphere_quadrature(cfg.light_samples)[1].shape[0], "precision": cfg.precision,
               "seconds": round(seconds, 1),
               "fp16 MB": round(table.size_bytes() / 1e6, 2), "fp16 bytes per vertex": table.size_bytes() //
               table.num_vertices}
        print_table("Full precompute", [row], width=200)
        record("full", [row])
    if "images" in stages:
        if a.table.is_file():
            table = SHPRT.load(a.table)
        else:  # the vertices the camera's samples need, the rest zero: the same pixels as the full table
            table, seconds = visible_table(model, points, normals, faces, camera, a.resolution, a.spp)
            results["visible"] = {"vertices": int((table.coefficients.abs().sum((1, 2, 3, 4)) > 0).sum()),
                                  "seconds": round(seconds, 1)}
        t = time.perf_counter()
        imgs = {"SH PRT": render_prt(table, env, camera, a.resolution, spp=a.spp)}
        sec = {"SH PRT": time.perf_counter() - t}
        for name, seed in (("network", 0), ("network, seed 1", 1)):
            t = time.perf_counter()
            imgs[name] = render_translucent(model, obj, env, camera, a.resolution, spp=a.model_spp, seed=seed)
            sec[name] = time.perf_counter() - t
        for name, seed in (("reference", 1), ("reference, seed 2", 2)):
            t = time.perf_counter()
            imgs[name] = render_translucent_reference(obj, env, camera, a.resolution, spp=a.reference_spp, seed=seed)
            sec[name] = time.perf_counter() - t
        rows = [{"image": test, "against": ref, "seconds": round(sec[test], 1), **scores(imgs[test], imgs[ref])}
                for test, ref in (("SH PRT", "network"), ("network, seed 1", "network"), ("SH PRT", "reference"),
                                  ("network", "reference"), ("reference, seed 2", "reference"))]
        print_table(f"Images {a.resolution}^2: SH PRT {a.spp} spp, network {a.model_spp} spp, reference "
                    f"{a.reference_spp} spp", rows, width=200)
        write_image_ldr(a.image_out, compare_image(imgs["reference"], {k: imgs[k] for k in
                                                                       ("SH PRT", "network", "reference, seed 2")},
                                                   tonemap="aces"))
        record("images", rows)


if __name__ == "__main__":
    np.seterr(all="ignore")
    main()
