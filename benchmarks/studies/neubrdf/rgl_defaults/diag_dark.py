"""Share of render energy vs loss weight carried by dark targets (f cos_i < eps) and by clamped negatives."""
import sys, json, torch, neumat
from neumat.fit.query_samplers import QUERY_SAMPLERS
torch.set_num_threads(1); EPS = 0.01
out = {}
for path in sys.argv[1:]:
    src = neumat.open_material(path); name = path.split('/')[-1].split('.')[0].replace('_rgb', '')
    r = {}
    per = {}
    for s in ('cosine', 'merl'):
        q = QUERY_SAMPLERS.get(s)(src)(2 ** 16, torch.Generator().manual_seed(0), 'cpu')
        with torch.no_grad(): f = src.eval(q).double()
        t = f.clamp(min=0) * q.wi[:, 2:3].clamp(min=0).double()
        per[s] = (f, t)
    fC, tC = per['cosine']; fM, tM = per['merl']
    dC, dM = tC < EPS, tM < EPS
    E = float(tC.sum())
    w = lambda t, e: t / (e + t)
    r['energy_share_dark'] = float(tC[dC].sum() / E)
    r['w_default_dark'] = float(w(tC, 1.0)[dC].sum() / w(tC, 1.0).sum())
    r['w_cos_eps_dark'] = float(w(tC, EPS)[dC].sum() / w(tC, EPS).sum())
    r['w_cm_eps_dark'] = float((w(tC, EPS)[dC].sum() + w(tM, EPS)[dM].sum()) / (w(tC, EPS).sum() + w(tM, EPS).sum()))
    out[name] = r
    print(name, json.dumps({k: round(v, 4) for k, v in r.items()}), flush=True)
json.dump(out, open('/tmp/rglexp/diag_dark.json', 'w'), indent=1)
