"""SH PRT precompute in bfloat16 against float32 (`PRTConfig.precision`): milliseconds per vertex, the time this
predicts for the whole mesh, and the relative RMS of the bf16 coefficients a_lm against the fp32 ones, on random
vertices of a NeuPreSS model's object.

    python benchmarks/studies/neupress/neupress_prt_precision.py --model bunny.nmat --observations bunny.npz [--vertices 200]

Results: benchmarks/studies/neupress/results/neupress_prt.md, section 5. torch runs on --threads threads.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import torch

from neumat.catalog.modelfile import load_model
from neumat.cli.common import print_table
from neumat.core.config import config_from_dict
from neumat.fit.translucent_observations import Observations
from neumat.methods.neupress.prt import SHPRT, PRTConfig, sphere_quadrature
from neumat.reflectance.translucent import TranslucentConfig, TranslucentObject
from neumat.render.mesh import object_mesh, vertex_normals


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--model", type=Path, required=True)
    p.add_argument("--observations", type=Path, required=True)
    p.add_argument("--vertices", type=int, default=200)
    p.add_argument("--view-bins", default="8x16")
    p.add_argument("--light-samples", default="60,32")
    p.add_argument("--threads", type=int, default=2)
    a = p.parse_args()
    torch.set_num_threads(a.threads)
    model = load_model(a.model)
    obj = TranslucentObject(config_from_dict(TranslucentConfig, Observations.load_source(a.observations)["object"]),
                            spp=1)
    points, faces = object_mesh(obj, 4)
    normals = vertex_normals(points, faces)
    idx = torch.randperm(points.shape[0], generator=torch.Generator().manual_seed(0))[:a.vertices]
    pts, nrm = points[idx].float(), normals[idx].float()
    vt, vp = (int(v) for v in a.view_bins.split("x"))
    rows = []
    for lights in (int(v) for v in a.light_samples.split(",")):
        tables = {}
        for precision in ("fp32", "bf16"):
            cfg = PRTConfig(view_theta=vt, view_phi=vp, light_samples=lights, precision=precision, batch_size=16384)
            t = time.perf_counter()
            tables[precision] = SHPRT.from_material(model, pts, nrm, cfg).coefficients.double()
            per_vertex = (time.perf_counter() - t) / len(idx)
            ref = tables["fp32"]
            rows.append({"counts": f"{vt}x{vp} x {sphere_quadrature(lights)[1].shape[0]}", "precision": precision,
                         "ms / vertex": round(per_vertex * 1e3, 2),
                         f"min for {points.shape[0]} vertices": round(per_vertex * points.shape[0] / 60, 1),
                         "a_lm rel. RMS vs fp32": float((tables[precision] - ref).pow(2).mean().sqrt()
                                                        / ref.pow(2).mean().sqrt())})
    print_table(f"SH PRT precision, {len(idx)} vertices of {a.observations.name}", rows, width=160)


if __name__ == "__main__":
    main()
