"""Picture BTFs generated from the shared PBR sets at the light and view directions of the SparseBTF paper's
figures (Kavoosi et al.), so that they can be set beside its measured UBO2014 images.

    python docs/btf_paper_angles.py [--size 100]

Rows: the six shared sets (100 x 100-texel crops at texel (300, 300), relief 4x the set's height scale, as
benchmarks/studies/btf/btf_real.py). Columns, (azimuth, elevation above the surface) of the incident light / the view as the
captions give them: Fig. 1 (0, 45) / (0, 90); Figs. 4 and 6 (270, 66.5) / (15, 79); Fig. 5 (0, 90) / (15, 30).
Radiance under a unit directional light, one stop brighter, tiles magnified 2x. Writes
docs/images/btf_paper_angles.png; about a minute on 2 cores.
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
SETS = ("Fabric02_1K_partial", "Leather05_1K_partial", "Metal027_1K", "Paper001_1K", "Plaster001_1K", "Wood092_1K")
#: figure -> ((light azimuth, elevation), (view azimuth, elevation)) in degrees, as the paper's captions
ANGLES = {"Fig. 1": ((0, 45), (0, 90)), "Figs. 4, 6": ((270, 66.5), (15, 79)), "Fig. 5": ((0, 90), (15, 30))}


def direction(azimuth: float, elevation: float) -> torch.Tensor:
    """Unit vector (1, 3) at `azimuth` about the normal and `elevation` above the surface plane (degrees)."""
    a, e = math.radians(azimuth), math.radians(elevation)
    return torch.tensor([[math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e)]])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--size", type=int, default=100)
    parser.add_argument("--shared", default=str(HERE.parent.parent / "shared" / "data" / "svbrdf"))
    args = parser.parse_args()
    t0, rows = time.perf_counter(), []
    for name in SETS:
        crop, relief = texture_tile(load_texture_set(Path(args.shared) / name), args.size, crop=args.size,
                                    row=300, col=300)
        tiles = []
        for figure, (light_angles, view_angles) in ANGLES.items():
            light, view = direction(*light_angles), direction(*view_angles)
            btf = generate_btf(crop, light, view, relief=4 * relief, spp=4)
            radiance = btf.data[0, 0] * light[0, 2]          # apparent BRDF x cos(light)
            tiles.append(labelled_tile(radiance, f"{name.split('_')[0]}, {figure}", exposure=1.0, magnify=2))
        rows.append(tiles)
    save_grid(rows, "btf_paper_angles", t0)


if __name__ == "__main__":
    main()
