"""Session 81: each GLSL export under GLSL 4.20 (its texel-fetched textures as images, `read_as_images`) and under
GLSL 3.30 (the same textures through samplers), interleaved round by round so that a loaded machine's drift
falls on both: evaluations per CPU second (`neumat.testing.parity.glsl_evals_per_second`, one llvmpipe thread,
best of 5) at 2^16 of the speed suite's queries, each round's rates and the ratio of the medians ("median ratio").

Conclusions: docs/formats/glsl.md (`neumat.export.glsl`).
Usage: python -m benchmarks.studies.speed.glsl_images [--models neubrdf,multiscale,...] [--rounds 4]
"""
from __future__ import annotations

import argparse
import os
import statistics
import sys

os.environ.setdefault("LP_NUM_THREADS", "1")

import torch  # noqa: E402

from benchmarks.suites.speed import queries, runtime_model  # noqa: E402
from neumat.export.glsl import export_glsl  # noqa: E402
from neumat.export.glsl_common import GLSL_IMAGE_VERSION, GLSL_VERSION  # noqa: E402
from neumat.testing.parity import glsl_evals_per_second  # noqa: E402


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--models", default="neumip-frame,neumip,neural-appearance,multiscale,neubrdf")
    parser.add_argument("--rounds", type=int, default=4)
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    for name in args.models.split(","):
        model = runtime_model(name, 0)
        q = queries(model, 2 ** 16, 0)
        for precision in ("fp32", "fp16"):
            export = export_glsl(model, precision)
            rates: dict[str, list[float]] = {GLSL_IMAGE_VERSION: [], GLSL_VERSION: []}
            for r in range(args.rounds):  # the order alternates round by round
                for version in (GLSL_IMAGE_VERSION, GLSL_VERSION)[::1 if r % 2 == 0 else -1]:
                    rates[version].append(glsl_evals_per_second(export, q, clock="cpu", repeats=5, version=version))
            images, samplers = rates[GLSL_IMAGE_VERSION], rates[GLSL_VERSION]
            print(f"{name:18s} {precision} images {' '.join(f'{x:.3g}' for x in images)} | samplers "
                  f"{' '.join(f'{x:.3g}' for x in samplers)} | median ratio "
                  f"{statistics.median(images) / statistics.median(samplers):.2f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
