"""NeuBRDF VQ training step at N_side 16 and 64, steps alternated in one process (one torch thread): medians
of per-step wall and CPU seconds and their ratio 64 / 16. Batch 8192, paper sizes (k 16, b 9, MLP 2 x 64).

    PYTHONPATH=src python benchmarks/neubrdf_step_ratio.py [rounds]
"""
import sys, time, torch
sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parent))
from neubrdf_speed import cosine_dirs, target, make_optimizer
from neumat.models.neubrdf import NeuBRDF
from neumat.core.query import Query
torch.set_num_threads(1)
batch, rounds = 8192, int(sys.argv[1]) if len(sys.argv) > 1 else 6
setups = {}
for n in (16, 64):
    torch.manual_seed(0)
    m = NeuBRDF(nside=n); setups[n] = (m, make_optimizer(m), torch.Generator().manual_seed(0), [], [])
def step(n):
    m, opt, gen, tw, tc = setups[n]
    wi, wo = cosine_dirs(batch, gen), cosine_dirs(batch, gen)
    q, y = Query(wi, wo), target(wi, wo)
    t0, c0 = time.perf_counter(), time.process_time()
    pred = m.eval(q); cos = wi[:, 2:3]
    loss = (torch.log1p(pred * cos) - torch.log1p(y * cos)).abs().mean()
    opt.zero_grad(set_to_none=True); loss.backward(); opt.step()
    return time.perf_counter() - t0, time.process_time() - c0
for r in range(rounds + 2):
    for n in (16, 64):
        w, c = step(n)
        if r >= 2: setups[n][3].append(w); setups[n][4].append(c)
med = lambda x: sorted(x)[len(x) // 2]
for n in (16, 64): print(n, f"wall {med(setups[n][3]):.3f} cpu {med(setups[n][4]):.3f}")
print(f"ratio wall {med(setups[64][3]) / med(setups[16][3]):.2f} cpu {med(setups[64][4]) / med(setups[16][4]):.2f}")
