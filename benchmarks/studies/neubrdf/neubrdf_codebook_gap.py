"""Where the codebook loses against the dense grid at the paper's sizes (issue 32, Table 4's ratio): one dense
N_side 64 grid fitted coarse to fine, then its held-out log error after each stage: k-means into 2^b codewords
(`quantize_from_dense`, before any VQ step), VQ training with K candidate codewords per slot, and the dense grid
trained as many more steps. Each stage is scored by the held-out log error and by the paper's Table 4 metric, the
MSE over the MERL table's cells (`merl_table_mse`, dominated by the specular peak on shiny materials).

    OMP_NUM_THREADS=1 PYTHONPATH=src python benchmarks/studies/neubrdf/neubrdf_codebook_gap.py merl_tables/gold-paint.binary \
        [--candidates 8 64] [--coarse-steps 1500] [--dense-steps 1000] [--vq-steps 1000]

Steps of 8192 cosine-weighted queries, loss log_cos, the model's own optimiser, lr 1e-2 (coarse) and 2.5e-3
(after it) halved at 1/2 and 3/4 of each stage, EMA 0.01; errors on 2^17 held-out queries (seed 7).
"""
from __future__ import annotations

import argparse
import copy
import time

import torch

from neumat.catalog.open_material import open_material
from neumat.fit.ema import EMA
from neumat.fit.query_samplers import QUERY_SAMPLERS
from neumat.metrics.hdr import reflectance_errors
from neumat.methods.neubrdf.model import NeuBRDF
from neumat.reflectance.tabulate import merl_table_mse, tabulate_merl

BATCH = 8192


def train(model: NeuBRDF, source, draw, gen: torch.Generator, steps: int, lr: float) -> NeuBRDF:
    """`steps` steps in place; the model ends with its EMA weights, in eval mode."""
    opt = model.optimizer(lr)
    ema = EMA(model, 0.01)
    model.train()
    for i in range(steps):
        rate = lr * 0.5 ** ((i >= steps // 2) + (i >= 3 * steps // 4))
        for group in opt.param_groups:
            group["lr"] = rate * group.get("lr_scale", 1.0)
        q = draw(BATCH, gen, torch.device("cpu"))
        with torch.no_grad():
            y = source.eval(q).clamp(min=0)
        c = q.wi[:, 2:3]
        loss = (torch.log1p(model.eval(q) * c) - torch.log1p(y * c)).abs().mean()
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        ema.update(model)
    model.load_state_dict(ema.state_dict())
    return model.train(False)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("material")
    ap.add_argument("--candidates", type=int, nargs="+", default=[8, 64])
    ap.add_argument("--coarse-steps", type=int, default=1500)
    ap.add_argument("--dense-steps", type=int, default=1000)
    ap.add_argument("--vq-steps", type=int, default=1000)
    a = ap.parse_args()
    torch.set_num_threads(1)
    source = open_material(a.material)
    draw = QUERY_SAMPLERS.get("cosine")(source)
    gen = torch.Generator().manual_seed(0)
    table = tabulate_merl(source)

    def scores(m: NeuBRDF) -> tuple[float, float]:
        return reflectance_errors(m, source, n=2 ** 17, seed=7)["log_err"], merl_table_mse(m, table)

    def row(label: str, m: NeuBRDF, dense: tuple[float, float] | None = None, seconds: bool = True) -> None:
        s = scores(m)
        cells = [f"{v:.4g}" + ("" if dense is None else f" ({v / d:.1f}x)") for v, d in zip(s, dense or s)]
        print(f"| {label} | {cells[0]} | {cells[1]} | {f'{time.perf_counter() - t0:.0f}' if seconds else ''} |",
              flush=True)

    print("| stage | held-out log error | MERL-table MSE (Table 4) | s |\n|---|---|---|---|")
    t0 = time.perf_counter()
    torch.manual_seed(0)
    model = NeuBRDF(nside=16, features="dense")
    model.init_from_targets(source.eval(draw(BATCH, torch.Generator().manual_seed(1), torch.device("cpu"))))
    train(model, source, draw, gen, a.coarse_steps, 1e-2)
    row(f"dense N_side 16, {a.coarse_steps} steps", model)
    train(model.regrid(64), source, draw, gen, a.dense_steps, 2.5e-3)
    dense = scores(model)
    row(f"regridded to N_side 64, {a.dense_steps} dense steps", model)
    for k in a.candidates:
        vq = copy.deepcopy(model).quantize_from_dense(candidates=k)
        row(f"k-means into 512 codewords (K = {k})", vq, dense, seconds=False)
        train(vq, source, draw, gen, a.vq_steps, 2.5e-3)
        row(f"then {a.vq_steps} VQ steps, {k} candidates", vq, dense)
    train(model, source, draw, gen, a.vq_steps, 2.5e-3)
    row(f"dense, {a.vq_steps} more steps", model)


if __name__ == "__main__":
    main()
