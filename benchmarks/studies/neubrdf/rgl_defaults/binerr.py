"""Per-elevation-bin errors of fitted models against their source, under cosine (wi, wo) queries:
energy ratio sum(f_hat cos_i) / sum(f cos_i) per bin and channel, and the log_cos error per bin.
usage: binerr.py SRC TAG [TAG...]"""
import sys, json
import numpy as np, torch
import neumat
from neumat.fit.query_samplers import QUERY_SAMPLERS
torch.set_num_threads(1)
BINS = [0, 45, 60, 70, 80, 90.01]
src = neumat.open_material(sys.argv[1])
q = QUERY_SAMPLERS.get('cosine')(src)(2 ** 17, torch.Generator().manual_seed(7), 'cpu')
with torch.no_grad():
    f = src.eval(q).double().clamp(min=0)
ci = q.wi[:, 2:3].clamp(min=0).double()
th = torch.rad2deg(torch.acos(torch.minimum(q.wi[:, 2], q.wo[:, 2]).clamp(-1, 1))).double()
t = f * ci
out = {}
for tag in sys.argv[2:]:
    m = neumat.open_material(f'/tmp/rglexp/{tag}.nmat')
    with torch.no_grad():
        fh = m.eval(q).double().clamp(min=0)
    th_ = fh * ci
    rows = []
    for a, b in zip(BINS[:-1], BINS[1:]):
        k = (th >= a) & (th < b)
        rows.append({'bin': f'{a}-{int(b)}', 'energy_share': float(t[k].sum() / t.sum()),
                     'ratio_rgb': [round(float(th_[k][:, c].sum() / t[k][:, c].sum()), 3) for c in range(3)],
                     'log_cos_err': float((torch.log1p(th_[k]) - torch.log1p(t[k])).abs().mean()),
                     'log_eps_err': float((torch.log(0.01 + th_[k]) - torch.log(0.01 + t[k])).abs().mean())})
    out[tag] = rows
    print('==', tag)
    for r in rows:
        print('  ', r)
    sys.stdout.flush()
json.dump(out, open('/tmp/rglexp/binerr_' + '_'.join(sys.argv[2:])[:80] + '.json', 'w'), indent=1)
