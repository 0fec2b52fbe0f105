"""Render the docs gallery: every shared RGL material on a sphere under every shared environment map.

    python docs/gallery.py [--spp 64] [--resolution 160]

Writes docs/images/gallery.png (rows: materials, columns: environment maps) and docs/gallery.md.
Needs ../shared/data (or $NEUMAT_SHARED_DATA).
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch
from PIL import Image, ImageDraw, ImageFont

from neumat import open_material
from neumat.io.shared_data import shared_data_dir
from neumat.color.tonemap import to_ldr
from neumat.render.render import render

HERE = Path(__file__).resolve().parent


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--spp", type=int, default=64)
    parser.add_argument("--resolution", type=int, default=160)
    args = parser.parse_args()
    data = shared_data_dir()
    if data is None:
        raise SystemExit("docs/gallery.py needs the shared data folder (../shared/data or $NEUMAT_SHARED_DATA)")
    materials = sorted((data / "rgl").glob("*.bsdf"))
    envmaps = sorted((data / "envmap").glob("*.hdr")) + sorted((data / "envmap").glob("*.exr"))
    font = ImageFont.load_default(size=14)
    rows, lines, t0 = [], [], time.perf_counter()
    for path in materials:
        material = open_material(path)
        tiles = []
        for env in envmaps:
            with torch.no_grad():
                img = render(material, scene="sphere", light=f"env:{env}", spp=args.spp, resolution=args.resolution)
            tile = Image.fromarray(np.round(to_ldr(img.cpu().numpy()) * 255).astype(np.uint8))
            ImageDraw.Draw(tile).text((4, 2), env.stem, fill=(255, 255, 255), font=font)
            tiles.append(np.asarray(tile))
        row = Image.fromarray(np.concatenate(tiles, axis=1))
        ImageDraw.Draw(row).text((4, args.resolution - 18), path.stem, fill=(255, 255, 0), font=font)
        rows.append(np.asarray(row))
        lines.append(f"| {path.stem} | {material.description.strip().splitlines()[0]} |")
    Image.fromarray(np.concatenate(rows, axis=0)).save(HERE / "images" / "gallery.png")
    seconds = time.perf_counter() - t0
    (HERE / "gallery.md").write_text(
        "# Gallery: the shared RGL materials under the shared environment maps\n\n"
        f"Rendered by `python docs/gallery.py --spp {args.spp} --resolution {args.resolution}` "
        f"({len(materials) * len(envmaps)} renders in {seconds:.0f} s on {torch.get_num_threads()} CPU threads): "
        "a sphere, direct illumination with MIS between environment importance sampling and the measured BRDF's "
        "own sampler (`neumat.render.render`), tone map: clip + sRGB.\n\n"
        "![gallery](images/gallery.png)\n\n| file | material |\n|---|---|\n" + "\n".join(lines) + "\n")
    print(f"wrote {HERE / 'images' / 'gallery.png'} and {HERE / 'gallery.md'} in {seconds:.0f} s")


if __name__ == "__main__":
    main()
