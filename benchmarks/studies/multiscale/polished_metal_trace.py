"""Issue 55 diagnostic: trace a fit as `neumat fit SET --model M --seed S --source-option crop=64
--source-option crop_origin=R,C --source-option samples=8` runs it (preset recommended, CPU recipe), printing every
`--every` steps the batch's Eq. 10 loss, its largest / 99th-percentile / median per-query relative error, the
gradient norm (and per top-level module), the prediction and target ranges and the decoder MLP's input and output
(log f) ranges; every 100 steps the five queries with the largest relative error and their share of the batch
loss; at the end the history, the FitWarnings and Eq. 10 / median relative error / mean log error on a fixed
8192-query validation batch with 64-sample targets. `--huber C` trains with Eq. 10 Huberised beyond relative residual C
(`relative_l2_huber` at C = 10). Results: results/polished_metal_stability.md.

    PYTHONPATH=$PWD/src python benchmarks/studies/multiscale/polished_metal_trace.py SET --model multiscale --seed 0
"""
import sys, json, math, argparse
import torch
torch.set_num_threads(1)
from neumat.catalog.open_material import open_material
from neumat.fit.preset import build_fit
from neumat.fit import trainer
from neumat.fit.losses import RelativeL2MixLoss

ap = argparse.ArgumentParser()
ap.add_argument("src"); ap.add_argument("--model", default="multiscale"); ap.add_argument("--seed", type=int, default=0)
ap.add_argument("--origin", default="480,480"); ap.add_argument("--steps", type=int, default=None)
ap.add_argument("--set", action="append", default=[]); ap.add_argument("--out", default=None)
ap.add_argument("--every", type=int, default=10)
ap.add_argument("--huber", type=float, default=0.0)
ap.add_argument("--eps", type=float, default=1e-6)
a = ap.parse_args()
r, c = (int(v) for v in a.origin.split(","))
src = open_material(a.src, crop=64, crop_origin=(r, c), samples=8)
overrides = {}
for s in a.set:
    k, v = s.split("="); overrides[k] = json.loads(v) if v[:1] in "0123456789-[{tf" else v
m, res = build_fit(a.model, "recommended", device=torch.device("cpu"), source=src, overrides=overrides, seed=a.seed)
rows = []; cur = {}
orig_norm = trainer._gradient_norm
def gn(params):
    n = orig_norm(params); cur["gnorm"] = float(n)
    per = {}
    for name, p in m.named_parameters():
        if p.grad is not None:
            key = name.split(".")[0]
            per[key] = per.get(key, 0.0) + float(p.grad.square().sum())
    cur["gparts"] = {k: math.sqrt(v) for k, v in per.items()}
    return n
trainer._gradient_norm = gn
class L(RelativeL2MixLoss):
    def forward(self, pred, target, q):
        sq = (pred - target).square().sum(-1)
        rel = sq / (pred.detach() + self.eps).square().sum(-1)
        cur.update(loss=float((self.weight * rel + (1 - self.weight) * sq).mean()), rel_max=float(rel.max()),
                   rel_q99=float(rel.quantile(0.99)), rel_med=float(rel.median()),
                   pred_max=float(pred.max()), pred_min=float(pred[pred > 0].min()) if (pred > 0).any() else 0.,
                   tgt_max=float(target.max()), tgt_q99=float(target.sum(-1).quantile(0.99)), sq_mean=float(sq.mean()))
        if cur.get("step", 0) % 100 == 99:
            i = rel.topk(5).indices
            print("outliers step", cur.get("step", 0) + 1, [(f"{float(pred[j].sum()):.2e}", f"{float(target[j].sum()):.2e}", f"{float(rel[j]):.1e}") for j in i], "share of loss", float(rel[i].sum() / rel.sum()), flush=True)
        if a.huber > 0:
            r = rel.sqrt()
            robust = torch.where(r > a.huber, 2 * a.huber * r - a.huber ** 2, rel)
            return (self.weight * robust + (1 - self.weight) * sq).mean()
        return super().forward(pred, target, q)
def hook(mod, inp, out):
    x = inp[0].detach(); cur["in_absmax"] = float(x.abs().max()); cur["in_std"] = float(x.std())
    cur["out_max"] = float(out.detach().max()); cur["out_min"] = float(out.detach().min())
m.mlp.register_forward_hook(hook)
step = [0]
orig_step = torch.optim.Adam.step
def st(self, *args, **kw):
    out = orig_step(self, *args, **kw)
    step[0] += 1
    cur["step"] = step[0]
    if step[0] % a.every == 0 or step[0] < 20:
        rows.append(dict(cur))
    return out
torch.optim.Adam.step = st
res_fit = trainer.fit(m, src, res.recipe, steps=a.steps, device="cpu", progress=False, loss=L(eps=a.eps))
for row in rows:
    print(f"{row['step']:5d} loss {row['loss']:.4g} relmax {row['rel_max']:.3g} relq99 {row['rel_q99']:.3g} relmed {row['rel_med']:.3g} "
          f"g {row['gnorm']:.3g} pred [{row['pred_min']:.2g},{row['pred_max']:.3g}] tgt {row['tgt_max']:.3g} "
          f"in {row['in_absmax']:.3g}/{row['in_std']:.3g} out [{row['out_min']:.3g},{row['out_max']:.3g}] "
          + " ".join(f"{k}:{v:.2g}" for k, v in row['gparts'].items()))
print("history", [(h["step"], round(h["loss"], 4)) for h in res_fit.history])
print("warnings", res_fit.warnings)
if a.out: json.dump({"rows": rows, "history": res_fit.history, "warnings": res_fit.warnings}, open(a.out, "w"))
from neumat.fit.query_samplers import QUERY_SAMPLERS
val_src = open_material(a.src, crop=64, crop_origin=(r, c), samples=64)
qv = QUERY_SAMPLERS.get("footprint")(val_src, m)(8192, torch.Generator().manual_seed(123), torch.device("cpu"))
with torch.no_grad():
    tv = val_src.eval(qv); pv = res_fit.model.eval(qv)
    relv = (pv - tv).square().sum(-1) / (pv + 1e-6).square().sum(-1)
    logv = ((pv.sum(-1) + 1e-3).log() - (tv.sum(-1) + 1e-3).log()).abs()
print(f"VAL eq10 {float(relv.mean()):.4g} relmed {float(relv.median()):.4g} relq99 {float(relv.quantile(.99)):.4g} logerr {float(logv.mean()):.4g}")
