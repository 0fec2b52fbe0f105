"""Issue 49: what keeping the derived textures (`neumat.core.tensors.derived_from`) does to the latent-texture
models' evaluation rate: each model at its default (paper-sized) config in runtime form, 2^16 queries, one thread,
CPU seconds, best of R; three ways interleaved per repeat: with autograd on (how the speed suite timed until this
change), without autograd but rebuilding the derived textures every call (the code before the change), and without
autograd keeping them (now).

Usage: python -m benchmarks.studies.speed.latent_eval_cache [--models a,b] [--n 65536] [--repeats 5]
"""
from __future__ import annotations

import argparse
import sys
import time

import torch

from benchmarks.suites.speed import queries, runtime_model
from neumat.metrics.flops import model_flops
from neumat.nn import angular_texture, latent_texture

KEPT = latent_texture.derived_from


def _rebuild(owner, key, params, make):
    return make()


def _seconds(fn) -> float:
    t = time.process_time()
    fn()
    return time.process_time() - t


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--models", default="multiscale,tripleplane,neumip,neumip-frame,nbrdf-uv")
    parser.add_argument("--n", type=int, default=2 ** 16)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    print("| model | flops/query | autograd on, evals/cpu s | no autograd, rebuilt | no autograd, kept | kept / rebuilt |")
    print("|---|---|---|---|---|---|")
    for name in args.models.split(","):
        m = runtime_model(name, 0)
        q = queries(m, args.n, 0)
        best = {"grad": 1e9, "rebuilt": 1e9, "kept": 1e9}
        for _ in range(args.repeats + 1):  # the first round warms up
            for way in best:
                patch = KEPT if way == "kept" else _rebuild
                latent_texture.derived_from = angular_texture.derived_from = patch
                if way == "grad":
                    s = _seconds(lambda: m.eval(q))
                else:
                    with torch.no_grad():
                        m.eval(q)  # builds what it keeps outside the timing, as a renderer's second call finds it
                        s = _seconds(lambda: m.eval(q))
                best[way] = min(best[way], s)
        latent_texture.derived_from = angular_texture.derived_from = KEPT
        rate = {k: args.n / v for k, v in best.items()}
        print(f"| {name} | {model_flops(m)} | {rate['grad']:.3e} | {rate['rebuilt']:.3e} | {rate['kept']:.3e} | "
              f"{rate['kept'] / rate['rebuilt']:.2f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
