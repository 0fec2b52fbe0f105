"""Seconds per training step of a latent-texture model on Wood092_1K (full 1K set, or a top-left crop), one thread,
the CPU recipe's batch (2^12), loss and Adam (0.99, 0.999) and EMA 0.005 as the trainer: per-phase means (source draw +
targets, forward, backward, optimiser, EMA) and the fastest model-only step.

Usage: OMP_NUM_THREADS=1 PYTHONPATH=src python benchmarks/studies/multiscale/latent_steptime.py MODEL CROP STEPS
(CROP 0: the full set)
"""
import sys
import time

import torch

torch.set_num_threads(1)
from neumat.catalog.open_material import open_material
from neumat.fit.query_samplers import QUERY_SAMPLERS
from neumat.fit.losses import LOSSES
from neumat.fit.ema import EMA
from neumat.methods.latent_mlp.train import config_for_source
import neumat.methods  # noqa
model_name = sys.argv[1]; crop = int(sys.argv[2]); steps = int(sys.argv[3]) if len(sys.argv) > 3 else 4
kw = {} if crop == 0 else {"crop": crop}
src = open_material("/work/shared/data/svbrdf/Wood092_1K", **kw)
from neumat.models.registry import MODELS
cls = MODELS.get(model_name)
torch.manual_seed(0)
model = cls(**config_for_source(src))
draw = QUERY_SAMPLERS.get("footprint")(src, model)
loss_fn = LOSSES.get("relative_l2_mix")()
own = model.optimizer(3e-3, (0.99, 0.999), 1e-15)
opt = own or torch.optim.Adam(model.parameters(), lr=3e-3, betas=(0.99, 0.999), eps=1e-15)
ema = EMA(model, 0.005)
g = torch.Generator().manual_seed(0)
T = {k: 0.0 for k in ("draw", "fwd", "bwd", "opt", "ema")}; M = []
for s in range(steps + 1):
    t0 = time.perf_counter()
    q = draw(1 << 12, g, "cpu")
    with torch.no_grad(): tgt = src.eval(q)
    t1 = time.perf_counter()
    loss = loss_fn(model.eval(q), tgt, q)
    t2 = time.perf_counter()
    opt.zero_grad(set_to_none=True); loss.backward()
    t3 = time.perf_counter()
    opt.step()
    t4 = time.perf_counter()
    ema.update(model)
    t5 = time.perf_counter()
    if s:
        M.append(t5 - t1)
        for k, v in zip(T, (t1 - t0, t2 - t1, t3 - t2, t4 - t3, t5 - t4)): T[k] += v
print(model_name, "crop", crop, {k: round(v / steps, 4) for k, v in T.items()},
      "total", round(sum(T.values()) / steps, 3), "loss", float(loss), "model_min", round(min(M), 3))
