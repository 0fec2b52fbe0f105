"""Image metrics of fitted models of one file under the comparison protocol (`neumat.render.comparison`, as
`neumat eval` at --spp 512 --resolution 128), the reference rendered once and cached in $WORK (default
/tmp/rgl_negative); one JSON line per model.

    python -m benchmarks.studies.neubrdf.rgl_negative.score SRC.bsdf MODEL.nmat [MODEL.nmat ...]
"""
from __future__ import annotations

import json
import os
import pickle
import sys
from pathlib import Path

import torch

from neumat.catalog.modelfile import load_model
from neumat.catalog.open_material import open_material
from neumat.render.comparison import image_comparison, reference_renders

WORK = Path(os.environ.get("WORK", "/tmp/rgl_negative"))


def main(src: str, models: list[str]) -> None:
    torch.set_num_threads(1)
    ref = open_material(src)
    cache = WORK / f"ref_{Path(src).name}.pkl"
    if not cache.exists():
        WORK.mkdir(parents=True, exist_ok=True)
        pickle.dump(reference_renders(ref, 512, 128, 0), open(cache.with_suffix(".tmp"), "wb"))
        os.replace(cache.with_suffix(".tmp"), cache)
    renders = pickle.load(open(cache, "rb"))
    for path in models:
        row = image_comparison(load_model(path), ref, 512, 128, seed=0, renders=renders)
        print(json.dumps({"source": Path(src).name, "model": path, **{k: round(v, 6) for k, v in row.items()}}),
              flush=True)


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2:])
