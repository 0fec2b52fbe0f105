"""Diagnostics of the cosine and merl query samplers on RGL files and MERL-like tables (no fits)."""
import sys, math, json
import numpy as np, torch
import neumat
from neumat.fit.query_samplers import QUERY_SAMPLERS
from neumat.io.rgl import read_rgl

torch.set_num_threads(1)
EPS = 0.01
N = 2 ** 16
srcs = sys.argv[1:]
out = {}

def deg(x):
    return torch.rad2deg(torch.acos(x.clamp(-1, 1)))

for path in srcs:
    src = neumat.open_material(path)
    name = path.split('/')[-1].split('.')[0].replace('_rgb', '')
    tmax = None
    if path.endswith('.bsdf'):
        th = np.degrees(read_rgl(path).fields['theta_i'])
        tmax = float(th[-2])   # last measured slice (the 90 deg slice is a copy of it)
    res = {'theta_i_last_measured': tmax}
    per = {}
    for sname in ('cosine', 'merl'):
        q = QUERY_SAMPLERS.get(sname)(src)(N, torch.Generator().manual_seed(0), 'cpu')
        with torch.no_grad():
            f = src.eval(q).double()
        ti, to = deg(q.wi[:, 2]).double(), deg(q.wo[:, 2]).double()
        ci = q.wi[:, 2:3].clamp(min=0).double()
        t = f.clamp(min=0) * ci
        per[sname] = (q, f, t, ti, to)
    # render importance: energy of f cos_i under cosine (wi, wo) ~ the image's measure (up to the lighting)
    _, fc, tc, tic, toc = per['cosine']
    for sname, (q, f, t, ti, to) in per.items():
        r = {}
        r['theta_i_q50_q90'] = [float(ti.quantile(.5)), float(ti.quantile(.9))]
        r['theta_o_q50_q90'] = [float(to.quantile(.5)), float(to.quantile(.9))]
        for a in (60, 70, 80):
            r[f'frac_ti>{a}'] = float((ti > a).double().mean())
            r[f'frac_to>{a}'] = float((to > a).double().mean())
        r['frac_either>70'] = float(((ti > 70) | (to > 70)).double().mean())
        if tmax is not None:
            r['frac_ti>last_measured'] = float((ti > tmax).double().mean())
        r['frac_neg'] = float((f < 0).double().mean())
        r['frac_zero_after_clamp'] = float((t <= 0).double().mean())
        med = float(t.median())
        r['median_t'] = med
        r['median_t_rgb'] = [float(x) for x in t.median(0).values]
        r['q999_over_median'] = float(t.flatten().quantile(.999) / max(med, 1e-12))
        r['max_over_median'] = float(t.max() / max(med, 1e-12))
        r['frac_t<eps'] = float((t < EPS).double().mean())
        r['frac_t<eps/10'] = float((t < EPS / 10).double().mean())
        # where the top 0.1 % of t lie
        k = max(1, int(0.001 * t.numel()))
        top = t.flatten().topk(k).indices // 3
        r['top0.1%_median_theta_o'] = float(to[top].median())
        r['top0.1%_median_theta_i'] = float(ti[top].median())
        r['top0.1%_frac_to>70'] = float((to[top] > 70).double().mean())
        # loss weights: |d loss / d log f_hat| at f_hat = f, per query-channel
        g = ((ti > 70) | (to > 70))[:, None].expand_as(t)
        for lname, e in (('log_cos', 1.0), ('log_cos_eps', EPS)):
            w = t / (e + t)
            r[f'wshare_grazing70_{lname}'] = float(w[g].sum() / w.sum())
            r[f'wmean_{lname}'] = float(w.mean())
        # energy share (render importance) in the grazing region
        r['energy_share_grazing70'] = float(t[g].sum() / t.sum())
        # chroma of grazing vs non-grazing energy
        gg = g[:, 0]
        cg = t[gg].sum(0); cn = t[~gg].sum(0)
        r['chroma_grazing'] = [float(x) for x in cg / cg.sum()]
        r['chroma_rest'] = [float(x) for x in cn / cn.sum()]
        # dark-noisy: fraction of t below eps among negatives' neighbourhood: share of log_cos_eps weight on t<eps
        w = t / (EPS + t)
        r['wshare_eps_on_t<eps'] = float(w[t < EPS].sum() / w.sum())
        r['lossshare_eps_const_err_on_t<eps'] = float((t < EPS).double().mean())
        res[sname] = r
    # the combined training distributions
    def combo(lname, e, mix):
        num = den = 0.0
        for sname, wt in mix:
            q, f, t, ti, to = per[sname]
            g = ((ti > 70) | (to > 70))[:, None].expand_as(t)
            w = t / (e + t)
            num += wt * float(w[g].mean() * g.double().mean()); den += wt * float(w.mean())
        return num / den
    res['setting_wshare_grazing70'] = {
        'cosine+log_cos (default)': combo('log_cos', 1.0, [('cosine', 1.0)]),
        'cosine+log_cos_eps': combo('log_cos_eps', EPS, [('cosine', 1.0)]),
        'cosine_merl+log_cos': combo('log_cos', 1.0, [('cosine', .5), ('merl', .5)]),
        'cosine_merl+log_cos_eps': combo('log_cos_eps', EPS, [('cosine', .5), ('merl', .5)]),
    }
    res['render_energy_share_grazing70'] = res['cosine']['energy_share_grazing70']
    out[name] = res
    print(name, json.dumps(res, indent=None), flush=True)

json.dump(out, open('/tmp/rglexp/diag.json', 'w'), indent=1)
