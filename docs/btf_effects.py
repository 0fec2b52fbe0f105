"""Picture the generator's measured-like effects on BTFs of real texture sets: one bounce of inter-reflection
and anisotropic fibres.

    python docs/btf_effects.py [--size 100] [--samples 64]

Rows: three shared PBR sets (100 x 100-texel crops at texel (300, 300), one texture texel per BTF texel, relief
4x the set's height scale, as benchmarks/studies/btf/btf_real.py). Columns: direct light only; with one bounce of
inter-reflection (`--interreflection`); the bounce alone, 8x brighter; direct light with fibres of anisotropy
0.8 along the height map's grain (`--fibres 0.8 --fibre-direction grain`). Lit from 40 degrees elevation on
the left, seen from the mirror direction (the specular highlight, where the fibres show), one stop brighter,
tiles magnified 2x. Writes docs/images/btf_effects.png; about a minute on 2 cores.
"""
from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import torch

from neumat.io.texture_set import load_texture_set
from neumat.reflectance.btf_generate import generate_btf, texture_tile
from picture_tiles import labelled_tile, save_grid

HERE = Path(__file__).resolve().parent
SETS = ("Leather05_1K_partial", "Plaster001_1K", "Fabric02_1K_partial")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--size", type=int, default=100)
    parser.add_argument("--samples", type=int, default=64, help="inter-reflection directions per hit")
    parser.add_argument("--shared", default=str(HERE.parent.parent / "shared" / "data" / "svbrdf"))
    args = parser.parse_args()
    elevation = math.radians(40)
    light = torch.tensor([[-math.cos(elevation), 0.0, math.sin(elevation)]])
    view = torch.tensor([[math.cos(elevation), 0.0, math.sin(elevation)]])
    t0, rows = time.perf_counter(), []
    for name in SETS:
        crop, relief = texture_tile(load_texture_set(Path(args.shared) / name), args.size, crop=args.size,
                                    row=300, col=300)
        images = {}
        for label, options in (("direct", {}), ("+ bounce", {"interreflection": args.samples}),
                               ("+ fibres", {"fibres": 0.8})):
            btf = generate_btf(crop, light, view, relief=4 * relief, spp=4, **options)
            images[label] = btf.data[0, 0] * light[0, 2]                  # radiance = apparent BRDF x cos(light)
        images = {"direct": images["direct"], "+ bounce": images["+ bounce"],
                  "bounce x 8": 8 * (images["+ bounce"] - images["direct"]).clamp(min=0),
                  "+ fibres": images["+ fibres"]}
        rows.append([labelled_tile(radiance, f"{name.split('_')[0]} {label}", exposure=1.0, magnify=2)
                     for label, radiance in images.items()])
    save_grid(rows, "btf_effects", t0)


if __name__ == "__main__":
    main()
