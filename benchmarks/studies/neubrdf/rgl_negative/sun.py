"""The measured values and a model's at the sun's configuration for a few pixels of the comparison sphere
(orthographic camera on +z, the sky's sun at elevation 35, azimuth 40 degrees): where the measured red is
negative. `python -m benchmarks.studies.neubrdf.rgl_negative.sun SRC.bsdf MODEL.nmat [...]`"""
from __future__ import annotations

import math
import sys

import numpy as np
import torch

from neumat.catalog.modelfile import load_model
from neumat.catalog.open_material import open_material
from neumat.core.query import Query

PIXELS = [(66, 69), (75, 60), (55, 75), (80, 80), (50, 50)]  # (row, col) of a 128^2 render


def main(src: str, models: list[str]) -> None:
    e, a = math.radians(35), math.radians(40)
    sun = torch.tensor([math.cos(e) * math.sin(a), math.sin(e), math.cos(e) * math.cos(a)])
    wis, wos = [], []
    for row, col in PIXELS:
        x, y = (col + 0.5 - 64) / 64, -(row + 0.5 - 64) / 64
        n = torch.tensor([x, y, math.sqrt(1 - x * x - y * y)])
        t = torch.linalg.cross(torch.tensor([0.0, 1.0, 0.0]), n)
        t = t / t.norm()
        frame = torch.stack([t, torch.linalg.cross(n, t), n])
        wis.append(frame @ sun)
        wos.append(frame @ torch.tensor([0.0, 0.0, 1.0]))
    q = Query(torch.stack(wis), torch.stack(wos))
    print("pixels", PIXELS)
    print("theta_i", np.degrees(np.arccos(q.wi[:, 2].numpy())).round(1), "theta_o",
          np.degrees(np.arccos(q.wo[:, 2].numpy())).round(1))
    print("measured\n", np.array2string(open_material(src).eval(q).numpy(), precision=6))
    for path in models:
        with torch.no_grad():
            print(path, "\n", np.array2string(load_model(path).eval(q).numpy(), precision=6))


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2:])
