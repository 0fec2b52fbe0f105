"""CPU seconds of `neupress_variance.py`'s candidates in larger Mitsuba calls: 500 bunny surface points, one light, 64
paths each (32k paths per call, like a view of `collect_observations`), traced 3 times per candidate, interleaved.
The first repetition includes kernel compilation; compare the later ones.

    nice -n 15 python -m benchmarks.studies.neupress.neupress_variance_cost base,no_interior_nee,rr20,no_interior_nee+rr20,orthogonal 3

Results: benchmarks/studies/neupress/results/neupress_variance.md.
"""
import json
import sys
import time

import torch

from .neupress_variance import Variant, CANDIDATES, BUNNY
from neumat.fit.translucent_observations import collect_observations
from neumat.reflectance.translucent import TranslucentConfig, TranslucentObject, call_seed
obj = TranslucentObject(TranslucentConfig(shape=BUNNY, media=("marble", "ketchup"), size_mm=4.0), spp=1)
obs = collect_observations(obj, 4, resolution=16, spp=1, seed=5)
obs = obs[torch.randperm(len(obs), generator=torch.Generator().manual_seed(0))[:500]]
eps = 1e-3 * obj.diagonal
o, d = obs.x.double() + eps * obs.wo.double(), -obs.wo.double()
light = torch.tensor([0.3, 0.5, 0.81], dtype=torch.float64); light /= light.norm()
names = sys.argv[1].split(",")
vs = {k: Variant(obj, *CANDIDATES[k]) for k in names}
for v in vs.values():
    v.trace(o[:8], d[:8], light, 4, 1)
cpu = {k: 0.0 for k in names}
for rep in range(int(sys.argv[2])):
    for k in names:
        t = time.process_time(); vs[k].trace(o, d, light, 64, call_seed(9, rep)); cpu[k] += time.process_time() - t
    print(rep, {k: round(c, 2) for k, c in cpu.items()}, flush=True)
print(json.dumps({k: {"cpu": cpu[k], "rel": cpu[k] / cpu[names[0]], "black": vs[k].cpu["black"] / sum(vs[k].cpu.values())} for k in names}))
