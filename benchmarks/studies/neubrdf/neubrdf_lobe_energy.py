"""Where a fitted BRDF's sharp lobe goes wrong (issue 32): per outgoing elevation, its directional albedo
int f cos dwi relative to the source's, in all and inside a cone around the mirror direction; then the ratio
model / source along the plane of incidence near the mirror direction.

    python benchmarks/studies/neubrdf/neubrdf_lobe_energy.py merl_tables/steel.binary A.nmat B.nmat [--cone-deg 10] [--samples 20]

The albedo is a Monte Carlo estimate with 2^samples directions per outgoing direction, half uniform on the
hemisphere and half uniform in the cone (balance heuristic; `neumat.testing.furnace.mirror_cone_samples`), the same directions for the source and every model
(so their ratio is far less noisy than either estimate). Printed ratios are model / source - 1 (channel means).
One torch thread.
"""
from __future__ import annotations

import argparse
import math

import torch

import neumat
from neumat.catalog.modelfile import load_model
from neumat.core.query import Query
from neumat.testing.furnace import mirror_cone_samples

THETA_O_DEG = (0, 20, 40, 60, 75)
OFFSETS_DEG = (-8, -3, -2, -1, -0.5, 0, 0.5, 1, 2, 3, 8)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("source", help="the reference material (any file `neumat.open_material` reads)")
    ap.add_argument("models", nargs="+", help="fitted model files (.nmat)")
    ap.add_argument("--cone-deg", type=float, default=10.0, help="half-angle of the cone around the mirror direction")
    ap.add_argument("--samples", type=int, default=20, help="log2 of the directions per outgoing direction")
    a = ap.parse_args()
    torch.set_num_threads(1)
    source = neumat.open_material(a.source)
    models = {path: load_model(path) for path in a.models}
    gen = torch.Generator().manual_seed(0)
    print("Directional albedo, model / source - 1 (in the cone around the mirror direction in brackets)\n")
    print("| theta_o | source albedo (cone) | " + " | ".join(models) + " |")
    print("|---|---|" + "---|" * len(models))
    with torch.no_grad():
        for deg in THETA_O_DEG:
            q, w, in_cone = mirror_cone_samples(math.radians(deg), math.radians(a.cone_deg), 2 ** a.samples, gen)
            cone_w = w * in_cone.unsqueeze(-1)
            ref = source.eval(q).float().clamp(min=0)
            total, in_c = float((ref * w).sum(0).mean()), float((ref * cone_w).sum(0).mean())
            cells = []
            for model in models.values():
                f = model.eval(q).float()
                cells.append(f"{float((f * w).sum(0).mean()) / total - 1:+.3f} "
                             f"({float((f * cone_w).sum(0).mean()) / in_c - 1:+.3f})")
            print(f"| {deg} | {total:.4f} ({in_c:.4f}) | " + " | ".join(cells) + " |")
        for deg in (0, 40):
            print(f"\nIn the plane of incidence at theta_o = {deg}: wi at the mirror direction + offset; model / source\n")
            print("| offset (deg) | source | " + " | ".join(models) + " |")
            print("|---|---|" + "---|" * len(models))
            t = math.radians(deg)
            ti = torch.tensor([math.radians(deg + o) for o in OFFSETS_DEG])
            wi = torch.stack([-ti.sin(), torch.zeros_like(ti), ti.cos()], -1)
            q = Query(wi, torch.tensor([[math.sin(t), 0.0, math.cos(t)]]).expand(len(OFFSETS_DEG), 3).contiguous())
            ref = source.eval(q).float().mean(-1)
            ratios = [model.eval(q).float().mean(-1) / ref for model in models.values()]
            for i, off in enumerate(OFFSETS_DEG):
                print(f"| {off:+g} | {float(ref[i]):.3f} | " + " | ".join(f"{float(r[i]):.3f}" for r in ratios) + " |")


if __name__ == "__main__":
    main()
