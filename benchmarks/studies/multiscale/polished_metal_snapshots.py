"""Issue 55 item 2: fit as `neumat fit SET --model M --preset P --seed S --source-option crop=64
--source-option crop_origin=R,C --source-option samples=8 -o OUT.nmat` does (same source, preset and trainer), but
also write the model as it stands after each step in `--at` (OUT.stepN.nmat; the raw weights, the recipe's EMA
not applied) and the loss history (OUT.history.json), so that a record that is not the final one (e.g. a fit's
lowest) can be evaluated with `neumat eval`. Results: results/polished_metal_stability.md.

    PYTHONPATH=$PWD/src python benchmarks/studies/multiscale/polished_metal_snapshots.py SET --model neumip-frame \
        --seed 0 --at 50 -o OUT.nmat
"""
import argparse
import json
import warnings
from pathlib import Path

import torch

from neumat.catalog.modelfile import save_model
from neumat.catalog.open_material import open_material
from neumat.fit.preset import build_fit
from neumat.fit.trainer import fit

ap = argparse.ArgumentParser()
ap.add_argument("src")
ap.add_argument("--model", default="neumip-frame")
ap.add_argument("--preset", default="recommended")
ap.add_argument("--seed", type=int, default=0)
ap.add_argument("--origin", default="480,480")
ap.add_argument("--at", type=int, action="append", default=[])
ap.add_argument("-o", "--out", required=True)
a = ap.parse_args()
torch.set_num_threads(1)
r, c = (int(v) for v in a.origin.split(","))
src = open_material(a.src, crop=64, crop_origin=(r, c), samples=8)
m, resolved = build_fit(a.model, a.preset, device=torch.device("cpu"), source=src, seed=a.seed)
out = Path(a.out)


def snapshot(record):
    if record["step"] in a.at:
        save_model(m.runtime(), out.with_suffix(f".step{record['step']}.nmat"), recipe=resolved.recipe,
                   source=a.src, metrics={"loss": record["loss"]})


with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    res = fit(m, src, resolved.recipe, device="cpu", progress=False, callback=snapshot)
save_model(res.model.runtime(), out, recipe=res.recipe, source=a.src, metrics={"final_loss": res.history[-1]["loss"]})
out.with_suffix(".history.json").write_text(json.dumps({"history": res.history, "warnings": res.warnings,
                                                        "ema": bool(getattr(res.recipe, "ema", 0))}, indent=1))
print(json.dumps({"final": res.history[-1]["loss"], "best": min(h["loss"] for h in res.history),
                  "warnings": res.warnings}))
