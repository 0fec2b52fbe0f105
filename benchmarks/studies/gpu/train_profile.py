"""Where a paper-recipe training step's time goes on a CUDA GPU: NeuBRDF (batch 2^14) and NBRDF (batch 512) on
rgl/paper_white, 20 warm-up steps, 60 timed, then torch.profiler over 30 steps (the top operators by CPU and by CUDA
time, kernel launches, synchronisations). `python -m benchmarks.studies.gpu.train_profile`."""
from __future__ import annotations

import time
import warnings
from dataclasses import replace

import torch
from torch.profiler import ProfilerActivity, profile

from neumat.catalog.open_material import open_material
from neumat.fit.preset import build_fit
from neumat.fit.trainer import fit
from neumat.io.shared_data import shared_data_dir


def main() -> None:
    warnings.simplefilter("ignore")  # a few dozen steps are timed, not judged
    source = open_material(shared_data_dir() / "rgl" / "paper_white_rgb.bsdf")
    for name in ("neubrdf", "nbrdf"):
        model, setting = build_fit(name, "paper", device="cuda", source=source, seed=0)
        model = model.cuda()
        recipe = replace(setting.recipe, log_every=10 ** 9, checkpoint_every=10 ** 9)
        fit(model, source, replace(recipe, steps=20), progress=False, device="cuda")
        torch.cuda.synchronize()
        t0 = time.perf_counter()
        fit(model, source, replace(recipe, steps=60), progress=False, device="cuda")
        torch.cuda.synchronize()
        print(name, "ms/step", 1e3 * (time.perf_counter() - t0) / 60, "batch", recipe.batch_size, flush=True)
        with profile(activities=[ProfilerActivity.CPU, ProfilerActivity.CUDA]) as prof:
            fit(model, source, replace(recipe, steps=30), progress=False, device="cuda")
        events = prof.key_averages()
        print(events.table(sort_by="self_cpu_time_total", row_limit=30, max_name_column_width=60))
        print(events.table(sort_by="self_cuda_time_total", row_limit=12, max_name_column_width=60))
        by_name = {e.key: e for e in events}
        for key in ("cudaStreamSynchronize", "cudaMemcpyAsync", "aten::item", "cudaLaunchKernel"):
            if key in by_name:
                print(key, "calls", by_name[key].count, "cpu ms", by_name[key].cpu_time_total / 1e3)


if __name__ == "__main__":
    main()
