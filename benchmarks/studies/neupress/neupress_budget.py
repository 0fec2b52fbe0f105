"""Issue 51's budget study: where a CPU budget for NeuPreSS's ground truth pays, at equal CPU time.

Three steps, each a subcommand (results: `results/neupress_budget.md`, which lists the exact sequence):

    python -m benchmarks.studies.neupress.neupress_budget trace -o v1.npz --views 1000 --spp 64 --view-seed 1 --path-seed 11
    python -m benchmarks.studies.neupress.neupress_budget combine mean s256.npz base.npz p1.npz p2.npz p3.npz
    python -m benchmarks.studies.neupress.neupress_budget score M.nmat [M2.nmat ...] --test test4096.npz --spp 256

`trace`: `collect_observations` of the bunny (marble / ketchup, 4 mm) with separate seeds for the views (lights,
cameras, ray jitter) and for the paths, so that sets with one view seed and several path seeds are the same
queries with independent paths (`combine mean` averages them into more paths per observation) and sets with
different view seeds are new queries (`combine cat` concatenates them); prints wall and CPU seconds.
`score`: the held-out error of each model on a separate 4096-spp test set as a fraction of the test values'
variance (the test set's own Monte Carlo noise is ~0.5 % of it), and the full appearance (surface reflection +
subsurface + background) at --res^2 under an environment map never used in development, MIS at --spp, against
a 4096-spp Mitsuba reference (cached beside the test set), with the second reference's score as the noise floor.
"""
from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from neumat.catalog.modelfile import load_model
from neumat.core.config import config_to_dict
from neumat.core.query import Query
from neumat.fit.translucent_observations import Observations, collect_observations
from neumat.metrics.image import image_metrics, masked_flip
from neumat.reflectance.translucent import TranslucentConfig, TranslucentObject
from neumat.render.envmaps import downsample_envmap, read_envmap
from neumat.render.lights import EnvironmentMap
from neumat.render.translucent import object_mask, orbit_camera, render_translucent, render_translucent_reference

MESH = "../shared/data/mesh/stanford_bunny_35k.ply"
ENV = "../shared/data/envmap/venice_sunset_1k.hdr"


def config(mesh: str) -> TranslucentConfig:
    return TranslucentConfig(shape=mesh, media=("marble", "ketchup"), size_mm=4.0)


def trace(a) -> None:
    cfg = config(a.mesh)
    obj = TranslucentObject(cfg, spp=a.spp, seed=a.path_seed)
    wall, cpu = time.perf_counter(), time.process_time()
    obs = collect_observations(obj, a.views, resolution=a.res, spp=a.spp, seed=a.view_seed)
    source = {"object": config_to_dict(cfg), "spp": a.spp, "seed": a.path_seed,
              "bbox": [obj.bbox_min.tolist(), obj.bbox_max.tolist()]}
    obs.save(a.out, source=source)
    print(json.dumps({"out": a.out, "observations": len(obs), "spp": a.spp, "views": a.views, "res": a.res,
                      "wall_s": time.perf_counter() - wall, "cpu_s": time.process_time() - cpu}))


def combine(a) -> None:
    sets = [Observations.load(p) for p in a.inputs]
    source = Observations.load_source(a.inputs[0])
    if a.mode == "mean":
        for s in sets[1:]:
            if not (torch.equal(s.x, sets[0].x) and torch.equal(s.wi, sets[0].wi)):
                raise SystemExit("combine mean: the sets are not the same queries (use one view seed)")
        out = replace(sets[0], value=torch.stack([s.value for s in sets]).mean(0))
        source["spp"] = sum(Observations.load_source(p)["spp"] for p in a.inputs)
    else:
        out = Observations(**{k: torch.cat([getattr(s, k) for s in sets]) for k in ("x", "n", "wo", "wi", "value")})
    out.save(a.out, source=source)
    print(json.dumps({"out": a.out, "observations": len(out), "spp": source["spp"]}))


def score(a) -> None:
    test = Observations.load(a.test)
    obj = TranslucentObject(config(a.mesh), spp=1, seed=0)
    env = EnvironmentMap(downsample_envmap(read_envmap(a.env), 128))
    camera = orbit_camera(obj, a.res)
    refs = []
    for k in (1, 2):
        path = Path(a.test).with_name(f"ref_{Path(a.env).stem}_{a.res}_{k}.npy")
        if not path.exists():
            np.save(path, render_translucent_reference(obj, env, camera, a.res, spp=4096, seed=k,
                                                       appearance="full").numpy())
        refs.append(np.load(path))
    mask = object_mask(obj, camera, a.res).numpy()

    def scores(img: np.ndarray) -> dict:
        s = image_metrics(refs[0], img, tonemap="aces")
        return {"flip": s["flip"], "ssim": s["ssim"], "object_flip": masked_flip(refs[0], img, mask, tonemap="aces"),
                "mse": float(((img - refs[0]) ** 2).mean())}

    variance = float(test.value.double().var(0).mean())
    print(json.dumps({"reference floor": scores(refs[1]), "test observations": len(test)}))
    for m in a.models:
        model = load_model(m, device="cpu")
        with torch.no_grad():
            pred = torch.cat([model.eval(Query(wi=test.wi[i:i + 8192], wo=test.wo[i:i + 8192], x=test.x[i:i + 8192],
                                               n=test.n[i:i + 8192])) for i in range(0, len(test), 8192)])
        row = {"model": m, "test_error_over_variance":
               float(((pred.double() - test.value.double()) ** 2).mean()) / variance}
        img = render_translucent(model, obj, env, camera, a.res, spp=a.spp, seed=0, appearance="full").numpy()
        row.update(scores(img), spp=a.spp)
        print(json.dumps(row), flush=True)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="command", required=True)
    t = sub.add_parser("trace")
    t.add_argument("-o", "--out", required=True)
    t.add_argument("--views", type=int, default=1000)
    t.add_argument("--res", type=int, default=32)
    t.add_argument("--spp", type=int, default=64)
    t.add_argument("--view-seed", type=int, default=0)
    t.add_argument("--path-seed", type=int, default=0)
    t.add_argument("--mesh", default=MESH)
    c = sub.add_parser("combine")
    c.add_argument("mode", choices=("mean", "cat"))
    c.add_argument("out")
    c.add_argument("inputs", nargs="+")
    s = sub.add_parser("score")
    s.add_argument("models", nargs="+")
    s.add_argument("--test", required=True)
    s.add_argument("--spp", type=int, default=256)
    s.add_argument("--res", type=int, default=64)
    s.add_argument("--env", default=ENV)
    s.add_argument("--mesh", default=MESH)
    a = p.parse_args()
    {"trace": trace, "combine": combine, "score": score}[a.command](a)


if __name__ == "__main__":
    main()
