"""Issue 55, session 68: does a latent-texture fit's image error settle, or swing, at the CPU recipe's constant rate?
Fit one selection-free crop as the protocol does (`selection_free.py`: `--source-option samples=32 --set
option.target_samples=32` at the recommended preset, here in-process) and score the raw weights every `--every`
steps, then the fitted (EMA) model, by the scale series `neumat eval --scales 9 --resolution 48` reads (reference
at 64 footprint samples). Prints one line per snapshot: step, the record's median step loss, mean FLIP.
Results: results/selection_free.md ("neumip-frame's one failing pair").

    python -m benchmarks.studies.multiscale.flip_during_fit ../shared/data/svbrdf/Wood092_1K --origin 208,244 \
        --model neumip-frame --seed 0 [--set recipe.schedule=halves]
"""
import argparse
import copy

import torch

from neumat.catalog.open_material import open_material
from neumat.cli.common import parse_overrides
from neumat.fit.preset import build_fit
from neumat.fit.trainer import fit
from neumat.render.scale_series import score_scale_series


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("set")
    ap.add_argument("--origin", required=True, help="R,C of the 64^2 crop")
    ap.add_argument("--model", default="neumip-frame")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--every", type=int, default=1000)
    ap.add_argument("--set", dest="overrides", action="append", default=[], help="KEY=VALUE, as neumat fit --set")
    a = ap.parse_args()
    torch.set_num_threads(1)
    origin = tuple(int(v) for v in a.origin.split(","))
    source = open_material(a.set, crop=64, crop_origin=origin, samples=32)
    reference = open_material(a.set, crop=64, crop_origin=origin, samples=64)
    overrides = {"option.target_samples": 32, **parse_overrides(a.overrides)}
    model, resolved = build_fit(a.model, source=source, overrides=overrides, seed=a.seed)
    snapshots = {}

    def keep(record: dict) -> None:
        if record["step"] % a.every == 0:
            snapshots[record["step"]] = (copy.deepcopy(model.state_dict()), record.get("loss_median", record["loss"]))

    result = fit(model, source, resolved.recipe, progress=False, callback=keep)
    print(f"{a.model} seed {a.seed} {a.overrides}: {result.steps} steps at lr {resolved.recipe.lr}, "
          f"schedule {resolved.recipe.schedule}, EMA {resolved.recipe.ema}; warnings {result.warnings}")
    for step, (state, loss) in sorted(snapshots.items()):
        raw = copy.deepcopy(model)
        raw.load_state_dict(state)
        raw.train(False)
        print(f"step {step}: loss median {loss:.6f}, FLIP {score_scale_series(raw, reference)['flip_mean']:.4f} "
              "(raw weights)", flush=True)
    print(f"fitted (EMA): FLIP {score_scale_series(model, reference)['flip_mean']:.4f}")


if __name__ == "__main__":
    main()
