"""Picture the procedural BTF materials: every class (rows) in variants 0..N-1 (columns).

    python docs/procedural_btfs.py [--variants 6] [--size 96]

Each tile is one image of the generated BTF (`neumat data btf-generate procedural:<class>~<variant>`): seen
straight down, lit from 60 degrees elevation (from the left), so that the relief casts shadows. Writes
docs/images/procedural_btfs.png. No data needed; about 10 s on 2 cores.
"""
from __future__ import annotations

import argparse
import math
import time

import torch

from neumat.reflectance.btf_generate import generate_btf
from neumat.reflectance.procedural_texture import KINDS, material_name, procedural_texture_set
from picture_tiles import labelled_tile, save_grid

def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--variants", type=int, default=6)
    parser.add_argument("--size", type=int, default=96)
    args = parser.parse_args()
    elevation = math.radians(60)
    light = torch.tensor([[-math.cos(elevation), 0.0, math.sin(elevation)]])
    view = torch.tensor([[0.0, 0.0, 1.0]])
    t0, rows = time.perf_counter(), []
    for kind in KINDS:
        tiles = []
        for variant in range(args.variants):
            ts = procedural_texture_set(kind, args.size, seed=1, variant=variant)
            btf = generate_btf(ts, light, view, relief=4.0 * args.size / 40, spp=4)
            radiance = btf.data[0, 0] * light[0, 2]                        # apparent BRDF x cos(light)
            tiles.append(labelled_tile(radiance, material_name(kind, variant)))
        rows.append(tiles)
    save_grid(rows, "procedural_btfs", t0)


if __name__ == "__main__":
    main()
