"""Training and evaluation speed of the gated multi-scale model against its FLOP-matched baselines.

Same setting as the training part of `benchmarks/studies/multiscale/multiscale.py` on the CPU (Wood092 at 64^2, model pyramids
64^2, batches of 1024 Sec. 4.2 footprint queries, 8-sample SVBRDF targets, short-run optimiser: Adam
(0.9, 0.999), lr 1e-2, EMA 0.02). For every model it prints, side by side:

- steps/s of `neumat.fit.trainer.fit` (the number the multiscale benchmark reports), best of `--repeats` runs
  of `--steps` steps;
- the time of one training step split into query drawing, target (source evaluation, the same for every
  model), forward (model + loss), backward, optimiser and EMA (best of `--repeats` blocks of `--steps` steps),
  and model-only steps/s (forward + backward + optimiser + EMA);
- evaluations/s of `model.eval` without gradient on 65536 footprint queries.

Models are measured in turn within each repeat and the best repeat is kept, which filters out the load of
a shared machine. Single-threaded by default (`--threads`).

    python benchmarks/studies/multiscale/multiscale_speed.py
    python benchmarks/studies/multiscale/multiscale_speed.py --models multiscale tripleplane --steps 50 --repeats 3
"""
from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

import torch

from neumat.fit.ema import EMA
from neumat.fit.footprint_queries import footprint_queries
from neumat.fit.losses import LOSSES
from neumat.fit.method import recipe_for
from neumat.fit.trainer import fit
from neumat.io.texture_set import load_texture_set
from neumat.models.registry import build_model
from neumat.reflectance.svbrdf import SVBRDF

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "svbrdf" / "Wood092_1K"
PHASES = ("draw", "target", "forward", "backward", "optimiser", "ema")


def short_run_recipe(name: str, steps: int, batch: int):
    """The recipe `benchmarks/studies/multiscale/multiscale.py --short-run-optimiser` trains `name` with."""
    return replace(recipe_for(name), steps=steps, batch_size=batch, lr=1e-2, betas=(0.9, 0.999), ema=0.02,
                   lr_decay_every=0, log_every=max(1, steps))


def fit_rate(name: str, source, size: int, steps: int, batch: int) -> float:
    """Steps per second of the trainer (fresh model, `steps` steps)."""
    torch.manual_seed(0)
    model = build_model({"type": name, "spatial_size": size})
    result = fit(model, source, short_run_recipe(model.name, steps, batch), device="cpu", progress=False)
    return result.steps / result.seconds


def phase_times(name: str, source, size: int, steps: int, batch: int) -> dict[str, float]:
    """Seconds per training step in each of PHASES (the trainer's step, taken apart)."""
    torch.manual_seed(0)
    model = build_model({"type": name, "spatial_size": size}).train()
    recipe = short_run_recipe(model.name, steps, batch)
    loss_fn = LOSSES.get(recipe.loss)()
    draw = footprint_queries(source, model)
    opt = torch.optim.Adam(model.parameters(), lr=recipe.lr, betas=tuple(recipe.betas), eps=recipe.eps)
    ema = EMA(model, recipe.ema)
    gen = torch.Generator().manual_seed(recipe.seed)
    total = dict.fromkeys(PHASES, 0.0)
    for step in range(steps + 2):  # two warm-up steps
        t = [time.perf_counter()]
        q = draw(batch, gen, "cpu")
        t.append(time.perf_counter())
        with torch.no_grad():
            target = source.eval(q)
        t.append(time.perf_counter())
        value = loss_fn(model.eval(q), target, q)
        t.append(time.perf_counter())
        opt.zero_grad(set_to_none=True)
        value.backward()
        t.append(time.perf_counter())
        opt.step()
        t.append(time.perf_counter())
        ema.update(model)
        t.append(time.perf_counter())
        if step >= 2:
            for k, a, b in zip(PHASES, t[:-1], t[1:]):
                total[k] += (b - a) / steps
    return total


def eval_rate(name: str, source, size: int, n: int, repeats: int = 3) -> float:
    """Evaluations per second of model.eval (no gradient) on n footprint queries."""
    torch.manual_seed(0)
    model = build_model({"type": name, "spatial_size": size}).train(False)
    q = footprint_queries(source, None)(n, torch.Generator().manual_seed(0), "cpu")
    with torch.no_grad():
        model.eval(q)
        t = time.perf_counter()
        for _ in range(repeats):
            model.eval(q)
    return n * repeats / (time.perf_counter() - t)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--material", default=str(DATA), help="texture-set folder")
    ap.add_argument("--models", nargs="*", default=["multiscale", "tripleplane", "neumip"])
    ap.add_argument("--max-size", type=int, default=64)
    ap.add_argument("--batch", type=int, default=1024)
    ap.add_argument("--samples", type=int, default=8, help="footprint samples of the targets")
    ap.add_argument("--steps", type=int, default=60, help="steps per timed run")
    ap.add_argument("--repeats", type=int, default=3, help="timed runs per model (the best is kept)")
    ap.add_argument("--eval-queries", type=int, default=1 << 16)
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    textures = load_texture_set(args.material, max_size=args.max_size)
    source = SVBRDF(textures, samples=args.samples)
    size = 1 << (max(textures.size).bit_length() - 1)
    print(f"{textures.name} at {textures.size[1]}x{textures.size[0]}, pyramids {size}^2, batch {args.batch}, "
          f"{args.samples}-sample targets, {args.threads} thread(s), best of {args.repeats} x {args.steps} steps")

    fits = {m: 0.0 for m in args.models}
    phases = {m: dict.fromkeys(PHASES, float("inf")) for m in args.models}
    evals = {m: 0.0 for m in args.models}
    for _ in range(args.repeats):
        for m in args.models:
            fits[m] = max(fits[m], fit_rate(m, source, size, args.steps, args.batch))
            times = phase_times(m, source, size, args.steps, args.batch)
            if sum(times.values()) < sum(phases[m].values()):
                phases[m] = times
            evals[m] = max(evals[m], eval_rate(m, source, size, args.eval_queries))

    print("\n| model | fit steps/s | " + " | ".join(f"{p} ms" for p in PHASES) + " | model-only steps/s | eval/s |")
    print("|---" * (len(PHASES) + 4) + "|")
    for m in args.models:
        t = phases[m]
        model_only = sum(t[k] for k in ("forward", "backward", "optimiser", "ema"))
        print(f"| {m} | {fits[m]:.2f} | " + " | ".join(f"{1e3 * t[p]:.2f}" for p in PHASES) +
              f" | {1 / model_only:.1f} | {evals[m]:.3g} |")


if __name__ == "__main__":
    main()
