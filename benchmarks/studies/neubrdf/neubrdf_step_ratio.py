"""NeuBRDF training step at N_side 16 and 64, steps of both alternated in one process (one torch thread):
medians of per-step wall and CPU seconds and their ratio 64 / 16. Batch 8192, paper sizes (k 16, b 9, MLP
2 x 64), the model's own optimiser (`NeuBRDF.optimizer`).

Arms (`--arms`): "vq" (the paper's end-to-end straight-through over all 2^b codewords), "dense" (features
per slot: the dense warm-up's steps), "vq-K" (after `quantize_from_dense(candidates=K)`: the VQ phase of a
dense warm-up with K candidate codewords per slot, recipe option vq_candidates).

    PYTHONPATH=src python benchmarks/studies/neubrdf/neubrdf_step_ratio.py [--rounds 8] [--arms vq dense vq-32]
"""
import argparse

import torch

from .neubrdf_speed import make_optimizer, timed_step

from neumat.methods.neubrdf.model import NeuBRDF


def build(arm: str, nside: int) -> NeuBRDF:
    """The model of `arm` at `nside` (a restricted VQ grid starts from the k-means of random dense features)."""
    torch.manual_seed(0)
    if arm in ("vq", "dense"):
        return NeuBRDF(nside=nside, features=arm)
    k = int(arm.removeprefix("vq-"))
    return NeuBRDF(nside=nside, features="dense").quantize_from_dense(iterations=2, candidates=k)


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--rounds", type=int, default=6)
    p.add_argument("--arms", nargs="+", default=["vq", "dense", "vq-32"])
    p.add_argument("--batch", type=int, default=8192)
    a = p.parse_args()
    torch.set_num_threads(1)
    for arm in a.arms:
        setups = {}
        for n in (16, 64):
            m = build(arm, n)
            setups[n] = (m, make_optimizer(m), torch.Generator().manual_seed(0), [], [])

        for r in range(a.rounds + 2):
            for n in (16, 64):
                m, opt, gen = setups[n][:3]
                w, c = timed_step(m, opt, gen, a.batch)
                if r >= 2:
                    setups[n][3].append(w)
                    setups[n][4].append(c)
        med = lambda x: sorted(x)[len(x) // 2]  # noqa: E731
        w16, c16, w64, c64 = med(setups[16][3]), med(setups[16][4]), med(setups[64][3]), med(setups[64][4])
        print(f"| {arm} | {w16:.3f} ({c16:.3f}) | {w64:.3f} ({c64:.3f}) | {w64 / w16:.2f} ({c64 / c16:.2f}) |",
              flush=True)


if __name__ == "__main__":
    main()
