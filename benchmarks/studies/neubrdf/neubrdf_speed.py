"""NeuBRDF speed on the CPU: training step time and evaluations per second.

Prints two tables:
- training: seconds per optimiser step (forward, log_cos loss, backward, Adam) for the "vq", "dense" and
  "lowbit" feature grids at several N_side (k 16, b 9, MLP 2 x 64), batch 8192 cosine-weighted queries;
  the optimiser is the model's own (`model.optimizer(lr, betas, eps)`) when it has one, else Adam; with
  --shared T also a SharedNeuBRDF of T materials (each batch split evenly over them; "vq" and "dense" only);
- evaluation: evaluations per second of `model.eval(q)` in training mode (idw weights, no gradient) and in
  `runtime()` mode, for batches 2^16 .. 2^20 (queries built beforehand), per wall-clock second and per
  CPU second of the process (the latter is less sensitive to other processes on a shared machine; with
  T threads on an idle machine the wall rate is at most T times the CPU rate); then the same model's GLSL
  export (`neumat.methods.neubrdf.glsl`) on the local OpenGL, llvmpipe on a CPU-only machine (marginal rate,
  `neumat.testing.parity.glsl_evals_per_second`), where a headless context can be created.

The machine load average is printed next to the numbers (timings on a shared machine are noisy).

    python benchmarks/studies/neubrdf/neubrdf_speed.py --threads 2
    python benchmarks/studies/neubrdf/neubrdf_speed.py --quick
"""
from __future__ import annotations

import argparse
import os
import time

import torch

from neumat.core.query import Query
from neumat.export.glsl import export_glsl
from neumat.methods.neubrdf.model import NeuBRDF
from neumat.methods.neubrdf.shared_model import MaterialQuery, SharedNeuBRDF
from neumat.testing.parity import glsl_evals_per_second, opengl_available


def cosine_dirs(n: int, gen: torch.Generator) -> torch.Tensor:
    """Cosine-weighted unit directions (n, 3) in the upper hemisphere."""
    u = torch.rand(n, 2, generator=gen)
    r, phi = u[:, 0].sqrt(), 2 * torch.pi * u[:, 1]
    return torch.stack([r * phi.cos(), r * phi.sin(), (1 - u[:, 0]).clamp(min=1e-6).sqrt()], -1)


def target(wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
    """A Lambert + Blinn-Phong lobe (N, 3), the supervision of the timed steps."""
    h = torch.nn.functional.normalize(wi + wo, dim=-1)
    return torch.tensor([0.2, 0.13, 0.06]) + 3.5 * h[:, 2:3].clamp(min=0) ** 20


def make_optimizer(model: NeuBRDF, lr: float = 1e-2):
    hook = getattr(model, "optimizer", None)
    if callable(hook):
        return hook(lr, (0.9, 0.999), 1e-8)
    return torch.optim.Adam(model.parameters(), lr=lr)


def timed_step(model: NeuBRDF | SharedNeuBRDF, opt, gen: torch.Generator, batch: int) -> tuple[float, float]:
    """(wall-clock, CPU) seconds of one training step of `model` on `batch` cosine queries of `target` (the
    queries and targets are drawn before the clock starts; a shared model's rows split evenly over its
    materials)."""
    wi, wo = cosine_dirs(batch, gen), cosine_dirs(batch, gen)
    q, y = Query(wi, wo), target(wi, wo)
    if isinstance(model, SharedNeuBRDF):
        q = MaterialQuery(wi, wo, material=torch.arange(batch) % model.cfg.num_materials)
    t0, c0 = time.perf_counter(), time.process_time()
    pred = model.eval(q)
    cos = wi[:, 2:3]
    loss = (torch.log1p(pred * cos) - torch.log1p(y * cos)).abs().mean()
    opt.zero_grad(set_to_none=True)
    loss.backward()
    opt.step()
    return time.perf_counter() - t0, time.process_time() - c0


def step_seconds(features: str, nside: int, batch: int, steps: int, warmup: int,
                 materials: int = 0) -> tuple[float, float]:
    """Median (wall-clock, CPU) seconds of one training step of a NeuBRDF, or of a SharedNeuBRDF of `materials`
    materials when > 0."""
    torch.manual_seed(0)
    gen = torch.Generator().manual_seed(0)
    model = SharedNeuBRDF(num_materials=materials, nside=nside, features=features) if materials else \
        NeuBRDF(nside=nside, features=features)
    opt = make_optimizer(model)
    times, cpu = [], []
    for i in range(warmup + steps):
        wall, proc = timed_step(model, opt, gen, batch)
        if i >= warmup:
            times.append(wall)
            cpu.append(proc)
    return sorted(times)[len(times) // 2], sorted(cpu)[len(cpu) // 2]


def evals_per_second(model: NeuBRDF, batch: int, repeats: int) -> tuple[float, float]:
    """(evaluations per wall-clock second, per CPU second of this process), best of `repeats`."""
    gen = torch.Generator().manual_seed(1)
    q = Query(cosine_dirs(batch, gen), cosine_dirs(batch, gen))
    wall, cpu = float("inf"), float("inf")
    with torch.inference_mode():
        model.eval(q)
        for _ in range(repeats):
            t0, c0 = time.perf_counter(), time.process_time()
            model.eval(q)
            wall, cpu = min(wall, time.perf_counter() - t0), min(cpu, time.process_time() - c0)
    return batch / wall, batch / cpu


def load() -> str:
    return "/".join(f"{x:.1f}" for x in os.getloadavg())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--threads", type=int, default=2, help="torch threads (default 2)")
    ap.add_argument("--nsides", type=int, nargs="+", default=[16, 32, 64])
    ap.add_argument("--features", nargs="+", default=["vq", "dense", "lowbit"])
    ap.add_argument("--batch", type=int, default=8192, help="training batch (default 8192)")
    ap.add_argument("--steps", type=int, default=5, help="timed training steps (median reported)")
    ap.add_argument("--eval-log2", type=int, nargs="+", default=[16, 18, 20], help="log2 of the eval batches")
    ap.add_argument("--eval-nside", type=int, default=64)
    ap.add_argument("--glsl-log2", type=int, default=18, help="log2 of the GLSL batch (0: skip the shader)")
    ap.add_argument("--shared", type=int, default=0, help="also time a SharedNeuBRDF of this many materials")
    ap.add_argument("--skip-train", action="store_true")
    ap.add_argument("--skip-eval", action="store_true")
    ap.add_argument("--quick", action="store_true", help="one N_side (16), 2 steps, batch 2^16 only")
    a = ap.parse_args()
    if a.quick:
        a.nsides, a.steps, a.eval_log2 = [16], 2, [16]
    torch.set_num_threads(a.threads)
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads, cpus {os.cpu_count()}")
    if not a.skip_train:
        print(f"\ntraining step, batch {a.batch} (median of {a.steps} steps)")
        print(f"{'model':>10} {'features':>8} {'nside':>6} {'s/step':>8} {'cpu-s':>8} {'load 1/5/15':>14}")
        for materials in [0] + ([a.shared] if a.shared else []):
            name = f"shared x{materials}" if materials else "neubrdf"
            for features in a.features:
                if materials and features == "lowbit":
                    continue
                for nside in a.nsides:
                    s, c = step_seconds(features, nside, a.batch, a.steps, warmup=2, materials=materials)
                    print(f"{name:>10} {features:>8} {nside:>6} {s:8.3f} {c:8.3f} {load():>14}", flush=True)
    if not a.skip_eval:
        print(f"\nevaluation, N_side {a.eval_nside}, vq: evals per wall second (per CPU second), best of 3")
        print(f"{'batch':>8} {'train-mode':>20} {'runtime()':>20} {'load 1/5/15':>14}")
        torch.manual_seed(0)
        model = NeuBRDF(nside=a.eval_nside)
        fast = NeuBRDF(nside=a.eval_nside)
        fast.load_state_dict(model.state_dict())
        fast.runtime()
        for lg in a.eval_log2:
            slow = evals_per_second(model, 2 ** lg, 2 if lg >= 20 else 3)
            rt = evals_per_second(fast, 2 ** lg, 3)
            cols = [f"{w:.3g} ({c:.3g})" for w, c in (slow, rt)]
            print(f"{'2^' + str(lg):>8} {cols[0]:>20} {cols[1]:>20} {load():>14}", flush=True)
        if a.glsl_log2 and opengl_available():
            gen = torch.Generator().manual_seed(1)
            q = Query(cosine_dirs(2 ** a.glsl_log2, gen), cosine_dirs(2 ** a.glsl_log2, gen))
            rate = glsl_evals_per_second(export_glsl(fast), q)
            print(f"GLSL export of runtime(), batch 2^{a.glsl_log2}: {rate:.3g} evals per wall second "
                  f"(llvmpipe here unless a GPU driver is present) {load():>14}")


if __name__ == "__main__":
    main()
