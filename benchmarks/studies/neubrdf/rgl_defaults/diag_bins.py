"""Per-elevation-bin view of the training targets: bins of max(theta_i, theta_o)."""
import sys, json
import numpy as np, torch
import neumat
from neumat.fit.query_samplers import QUERY_SAMPLERS
torch.set_num_threads(1)
EPS = 0.01; N = 2 ** 16
BINS = [0, 45, 60, 70, 80, 85, 88, 90.01]
out = {}
for path in sys.argv[1:]:
    src = neumat.open_material(path)
    name = path.split('/')[-1].split('.')[0].replace('_rgb', '')
    per = {}
    for s in ('cosine', 'merl'):
        q = QUERY_SAMPLERS.get(s)(src)(N, torch.Generator().manual_seed(0), 'cpu')
        with torch.no_grad():
            f = src.eval(q).double()
        ci = q.wi[:, 2:3].clamp(min=0).double()
        t = f.clamp(min=0) * ci
        th = torch.rad2deg(torch.acos(torch.minimum(q.wi[:, 2], q.wo[:, 2]).clamp(-1, 1))).double()
        per[s] = (f, t, th)
    medc = float(per['cosine'][1].median())
    rows = []
    fC, tC, thC = per['cosine']; fM, tM, thM = per['merl']
    # the trained distribution of cosine_merl: half each
    wC = tC / (EPS + tC); wM = tM / (EPS + tM)
    w1C = tC / (1 + tC); w1M = tM / (1 + tM)
    tot_eps = float(wC.sum() + wM.sum()); tot_1 = float(w1C.sum() + w1M.sum()); tot_def = float(w1C.sum())
    tot_E = float(tC.sum())
    for a, b in zip(BINS[:-1], BINS[1:]):
        mC = (thC >= a) & (thC < b); mM = (thM >= a) & (thM < b)
        row = {'bin': f'{a}-{int(b)}',
               'q_cos': float(mC.double().mean()), 'q_merl': float(mM.double().mean()),
               'render_energy': float(tC[mC].sum() / tot_E),
               'w_default(cos,log_cos)': float(w1C[mC].sum() / tot_def),
               'w_cm+eps': float((wC[mC].sum() + wM[mM].sum()) / tot_eps),
               'w_cm+log_cos': float((w1C[mC].sum() + w1M[mM].sum()) / tot_1),
               'merl_med_t/med_cos': float(tM[mM].median() / medc) if mM.any() else None,
               'merl_p99_t/med_cos': float(tM[mM].flatten().quantile(.99) / medc) if mM.any() else None,
               'merl_neg': float((fM[mM] < 0).double().mean()) if mM.any() else None,
               'merl_t<eps': float((tM[mM] < EPS).double().mean()) if mM.any() else None}
        rows.append(row)
    out[name] = rows
    print('==', name, 'median t (cosine) %.4g' % medc)
    print('  '.join(k[:13].rjust(13) for k in rows[0]))
    for r in rows:
        print('  '.join((('%13.4g' % v) if isinstance(v, float) else str(v).rjust(13)) for v in r.values()))
    sys.stdout.flush()
json.dump(out, open('/tmp/rglexp/diag_bins.json', 'w'), indent=1)
