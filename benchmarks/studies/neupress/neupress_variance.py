"""Variance and CPU cost of NeuPreSS's ground-truth estimator (`TranslucentObject.trace`) and cheap unbiased
variants of it (issue 51, item 2): Mitsuba samplers, volpath's Russian-roulette depth, the `volpathmis` integrator,
and the black-interior trace's share of the cost.

    nice -n 15 python benchmarks/studies/neupress/neupress_variance.py [--queries 2000] [--views 40] [--spp 64]
        [--reps 6] [--ref-spp 4096] [--candidates base,stratified,...]

Queries: `--queries` observations of `collect_observations` (`--views` views) of the Stanford bunny, marble /
ketchup, 4 mm. Every candidate traces all queries `--reps` times with fresh seeds, interleaved (rep 1 of every
candidate, then rep 2, ...), so that machine load affects them alike. Variance: per query and channel, the sample
variance over the reps, averaged over queries and channels; CPU: process CPU seconds (all of Mitsuba's threads) per
pass over the queries. Efficiency = 1 / (variance x CPU), relative to `base`. Bias: the mean over queries and
channels of (candidate's mean over its reps) - (reference: today's estimator at `--ref-spp`), in standard errors
(from the per-query spreads of both). Results: benchmarks/studies/neupress/results/neupress_variance.md.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import math
import time

import numpy as np
import torch

from neumat.fit.translucent_observations import collect_observations
from neumat.reflectance import translucent
from neumat.reflectance.translucent import TranslucentConfig, TranslucentObject, call_seed

BUNNY = "/work/shared/data/mesh/stanford_bunny_35k.ply"

#: name -> (integrator overrides, sampler type, TranslucentConfig overrides); "base" is the estimator before issue 51
#: item 2 (independent sampler, volpath rr_depth 5, interior emitter sampling on)
NEE_ON = {"interior_emitter_sampling": True, "rr_depth": 5, "sampler": "independent"}
NEE_OFF = {**NEE_ON, "interior_emitter_sampling": False}
CANDIDATES = {
    "base": ({}, "independent", NEE_ON),
    "stratified": ({}, "stratified", NEE_ON),
    "multijitter": ({}, "multijitter", NEE_ON),
    "ldsampler": ({}, "ldsampler", NEE_ON),
    "orthogonal": ({}, "orthogonal", NEE_ON),
    "rr1": ({"rr_depth": 1}, "independent", NEE_ON),
    "rr20": ({"rr_depth": 20}, "independent", NEE_ON),
    "rr100": ({"rr_depth": 100}, "independent", NEE_ON),
    "rr_off": ({"rr_depth": 100000}, "independent", NEE_ON),
    "volpathmis": ({"type": "volpathmis"}, "independent", NEE_ON),
    "no_interior_nee": ({}, "independent", NEE_OFF),
    "no_interior_nee+rr_off": ({"rr_depth": 100000}, "independent", NEE_OFF),
    "no_interior_nee+rr20": ({"rr_depth": 20}, "independent", NEE_OFF),
    "orthogonal+no_interior_nee+rr20": ({"rr_depth": 20}, "orthogonal", NEE_OFF),
}


class Variant:
    """Traces like `TranslucentObject.trace` with another integrator / sampler, timing both interiors."""

    def __init__(self, obj: TranslucentObject, integrator: dict, sampler: str, config: dict) -> None:
        self.obj, self.sampler = obj, sampler
        mi = obj.mi
        self.scenes = {}
        cfg = dataclasses.replace(obj.config, **config)
        for interior in ("medium", "black"):
            desc = translucent._scene_dict(cfg, translucent.outer_shape_dict(obj.config), interior, *obj._grids)
            desc["integrator"] = {**desc["integrator"], **integrator}
            self.scenes[interior] = mi.load_dict(desc)
        self.params = {k: mi.traverse(s) for k, s in self.scenes.items()}
        self.cpu = {"medium": 0.0, "black": 0.0}

    def set_light(self, light: torch.Tensor) -> None:
        to_world = self.obj.mi.ScalarTransform4f().look_at(origin=[0, 0, 0], target=(-light).tolist(),
                                                           up=translucent._up(light))
        for params in self.params.values():
            params[self.obj._light_key] = to_world
            params.update()

    def radiance(self, interior: str, o, d, seed: int, spp: int) -> torch.Tensor:
        mi = self.obj.mi
        t = time.process_time()
        scene = self.scenes[interior]
        sampler = mi.load_dict({"type": self.sampler, "sample_count": spp})
        sampler.set_samples_per_wavefront(sampler.sample_count())  # lanes k*spp .. k*spp+spp-1: one pixel's samples
        sampler.seed(seed, o.shape[0])
        value, _, _ = scene.integrator().sample(scene, sampler, self.obj._ray(o, d))
        out = torch.from_numpy(np.array(value, dtype=np.float64).T.copy())
        self.cpu[interior] += time.process_time() - t
        return out

    def trace(self, o, d, light, spp: int, seed: int) -> torch.Tensor:
        if self.sampler == "orthogonal":  # Mitsuba rounds the count to a prime square: 49 for 64
            spp = int(self.obj.mi.load_dict({"type": "orthogonal", "sample_count": spp}).sample_count())
        self.set_light(light)
        oo, dd = o.repeat_interleave(spp, 0), d.repeat_interleave(spp, 0)
        out = torch.zeros(o.shape[0], 3, dtype=torch.float64)
        per_call = max(1, translucent.WAVEFRONT // spp)
        for start in range(0, o.shape[0], per_call):
            sl = slice(start * spp, min(o.shape[0], start + per_call) * spp)
            s = call_seed(seed, start)
            diff = self.radiance("medium", oo[sl], dd[sl], s, spp) - self.radiance("black", oo[sl], dd[sl], s, spp)
            out[start:start + per_call] = diff.reshape(-1, spp, 3).mean(1)
        return out


def trace_all(variant: Variant, groups, n: int, spp: int, seed: int) -> torch.Tensor:
    out = torch.zeros(n, 3, dtype=torch.float64)
    for k, (idx, o, d, light) in enumerate(groups):
        out[idx] = variant.trace(o, d, light, spp, call_seed(seed, k))
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--queries", type=int, default=2000)
    p.add_argument("--views", type=int, default=40)
    p.add_argument("--spp", type=int, default=64)
    p.add_argument("--reps", type=int, default=6)
    p.add_argument("--ref-spp", type=int, default=4096)
    p.add_argument("--candidates", default=",".join(CANDIDATES))
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", default=None, help="write the raw numbers here")
    p.add_argument("--cost-batches", type=int, default=4,
                   help="CPU per pass also measured with the queries in this many calls (one light each, about "
                        "--queries / this rays x --spp paths per call, as a view of `collect_observations`)")
    p.add_argument("--cost-reps", type=int, default=3)
    a = p.parse_args()
    cfg = TranslucentConfig(shape=BUNNY, media=("marble", "ketchup"), size_mm=4.0)
    obj = TranslucentObject(cfg, spp=1, seed=a.seed)
    obs = collect_observations(obj, a.views, resolution=16, spp=1, seed=a.seed)
    pick = torch.randperm(len(obs), generator=torch.Generator().manual_seed(a.seed))[:a.queries]
    obs = obs[pick]
    n = len(obs)
    eps = 1e-3 * obj.diagonal
    groups = []
    lights, inverse = torch.unique(obs.wi.double(), dim=0, return_inverse=True)
    for k in range(lights.shape[0]):
        idx = (inverse == k).nonzero().squeeze(1)
        o = obs.x[idx].double() + eps * obs.wo[idx].double()
        groups.append((idx, o, -obs.wo[idx].double(), lights[k]))
    print(f"{n} queries in {len(groups)} light groups", flush=True)
    names = a.candidates.split(",")
    variants = {name: Variant(obj, *CANDIDATES[name]) for name in names}
    for v in variants.values():  # compile the kernels outside the timings
        trace_all(v, groups[:1], n, 4, 999)
        v.cpu = {"medium": 0.0, "black": 0.0}
    values = {name: [] for name in names}
    for rep in range(a.reps):
        for name in names:
            values[name].append(trace_all(variants[name], groups, n, a.spp, 1000 * rep + 17))
        print(f"rep {rep + 1}/{a.reps} done", flush=True)
    # cost in larger calls (the light per call is arbitrary: only the CPU is kept)
    cost = {name: 0.0 for name in names}
    order = torch.randperm(n, generator=torch.Generator().manual_seed(1))
    batches = [order[b::a.cost_batches] for b in range(a.cost_batches)]
    for rep in range(a.cost_reps):
        for name in names:
            t = time.process_time()
            for b, idx in enumerate(batches):
                o = obs.x[idx].double() + eps * obs.wo[idx].double()
                variants[name].trace(o, -obs.wo[idx].double(), lights[b % lights.shape[0]], a.spp,
                                     call_seed(77, rep, b))
            cost[name] += (time.process_time() - t) / a.cost_reps
    if a.cost_reps:
        print("batched cost done", flush=True)
    ref = None
    if a.ref_spp:
        t = time.process_time()
        ref_variant = Variant(obj, *CANDIDATES["base"])
        ref = trace_all(ref_variant, groups, n, a.ref_spp, 123456789)
        print(f"reference {a.ref_spp} spp: {time.process_time() - t:.0f} CPU s", flush=True)
    base_var = base_cpu = None
    rows, raw = [], {}
    for name in names:
        v = torch.stack(values[name])  # (reps, n, 3)
        var_q = v.var(0)  # per query and channel, unbiased over reps
        var = float(var_q.mean())
        cpu = sum(variants[name].cpu.values()) / a.reps
        black_share = variants[name].cpu["black"] / sum(variants[name].cpu.values())
        # uncertainty of the mean variance: over queries (heavy tails make it wide)
        var_se = float(var_q.mean(-1).std() / math.sqrt(n))
        if name == names[0]:
            base_var, base_cpu = var, cpu
        if name == names[0]:
            base_cost = cost[name]
        row = {"candidate": name, "variance rel.": var / base_var, "var rel. +-": var_se / base_var,
               "CPU s rel.": cpu / base_cpu, "efficiency": base_var * base_cpu / (var * cpu),
               "CPU s / pass": cpu, "black share": black_share,
               **({} if not a.cost_reps else
                  {"batched CPU s / pass": cost[name], "batched CPU s rel.": cost[name] / base_cost,
                   "batched efficiency": base_var * base_cost / (var * cost[name])}),
               "zero fraction": float((v == 0).all(-1).double().mean())}
        if ref is not None:
            d = v.mean(0) - ref  # (n, 3)
            diffs = []
            for c in range(3):
                dc = d[:, c]
                diffs.append(float(dc.mean() / (dc.std() / math.sqrt(n))))
            row["bias (SE) R,G,B"] = ", ".join(f"{x:+.1f}" for x in diffs)
            row["mean rel. to ref"] = ", ".join(f"{x:.3f}" for x in (v.mean((0, 1)) / ref.mean(0)).tolist())
        rows.append(row)
        raw[name] = {"values": v.tolist(), "cpu": variants[name].cpu}
    for r in rows:
        print(json.dumps(r), flush=True)
    if a.json:
        with open(a.json, "w") as f:
            json.dump({"rows": rows, "args": vars(a), "ref": None if ref is None else ref.tolist(), "raw": raw}, f)


if __name__ == "__main__":
    main()
