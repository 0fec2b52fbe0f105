"""NeuBRDF's paper recipe, whole (20000 steps at 2^14), on rgl/paper_white on a CUDA GPU, through the library's
trainer: the loss every 500 steps with the wall time, one JSON line each, to OUT/paper_fit.jsonl; the fitted model's
runtime form to OUT/paper_fit.nmat. `python -m benchmarks.studies.gpu.paper_fit OUT`."""
from __future__ import annotations

import json
import sys
import time
from dataclasses import replace
from pathlib import Path

from neumat.catalog.modelfile import save_model
from neumat.catalog.open_material import open_material
from neumat.fit.preset import build_fit
from neumat.fit.trainer import fit
from neumat.io.shared_data import shared_data_dir


def main(out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    source = open_material(shared_data_dir() / "rgl" / "paper_white_rgb.bsdf")
    model, setting = build_fit("neubrdf", "paper", device="cuda", source=source, seed=0)
    recipe = replace(setting.recipe, log_every=500, checkpoint_every=10 ** 9)
    print("preset", setting.preset, "recipe", setting.recipe_name, recipe.steps, "x", recipe.batch_size, flush=True)
    t0 = time.perf_counter()
    with open(out / "paper_fit.jsonl", "w") as log:
        def record(entry: dict) -> None:
            entry = {k: float(v) if hasattr(v, "__float__") else v for k, v in entry.items()}
            log.write(json.dumps({**entry, "wall_s": time.perf_counter() - t0}, default=str) + "\n")
            log.flush()
        fit(model.cuda(), source, recipe, progress=False, device="cuda", callback=record)
    print("wall s", time.perf_counter() - t0, flush=True)
    save_model(model.cpu().train(False).runtime(), out / "paper_fit.nmat")


if __name__ == "__main__":
    main(Path(sys.argv[1]))
