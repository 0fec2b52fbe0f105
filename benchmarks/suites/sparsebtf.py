"""sparsebtf: SparseBTF (Kavoosighafi et al. 2024) against PCA at equal bytes on a generated BTF (no measured BTF
could be obtained), through `neumat fit-many`."""
from __future__ import annotations

from pathlib import Path

from .. import harness
from .common import cli, fit_many, quality_rows

NAME = "sparsebtf"
DESCRIPTION = "SparseBTF against PCA at equal bytes on generated procedural BTFs, through fit-many"
BUDGET = {
    "quick": {"ours": "one procedural BTF (bumps) at 20^2 texels, 17 x 17 directions (rings:3x30), 1 spp, both models at their recipes, SparseBTF with 2 dictionaries and 2 training steps",
              "paper": "dictionary training on 10 UBO2014 BTFs, tested on the others", "expected_wall": "about 60 s"},
    "full": {"ours": "the five procedural classes at 40^2 texels, 4 spp, both models at their recipes, seeds 0 and 1",
             "paper": "dictionary training on 10 UBO2014 BTFs, tested on the others (not available to us)",
             "expected_wall": "about 1 h (generation dominates)"},
}
CLASSES = ("bumps", "weave", "bricks", "dents", "ridges")


def run(run: harness.Run) -> None:
    """Generate the BTFs, fit both models and tabulate."""
    classes, size, spp = (CLASSES[:1], 20, 1) if run.quick else (CLASSES, 40, 4)
    directions = ["--directions", "rings:3x30"] if run.quick else []  # hemi151 (the full runs') is 64x the data
    with run.folder("btf-generate", classes, size, spp, directions) as folder:
        sources = [str(_generated(folder, kind, size, spp, directions)) for kind in classes]
        quick = ["--set", "sparse-btf:num_dictionaries=2", "--set", "sparse-btf:steps=2", "--n-configs", "4096"]
        options = (quick if run.quick else ["--n-configs", str(2 ** 18)]) + ["--image-spp", "0"]
        rows = fit_many(run, sources, ["sparse-btf", "pca-btf"], options,
                        [run.seed] if run.quick else [run.seed, run.seed + 1])
    run.table("fits", "Generated BTFs x models (bytes: each model's own size; PCA's rank follows SparseBTF's bytes "
                      "in the pca-btf recipe)", quality_rows(rows))


def _generated(folder: Path, kind: str, size: int, spp: int, directions: list[str]) -> Path:
    """folder/<kind>.nbtf, generated unless a finished one is there (a --work folder keeps it for reruns)."""
    path = folder / f"{kind}.nbtf"
    if not path.exists():
        partial = folder / f"{kind}.partial.nbtf"
        cli(["data", "btf-generate", f"procedural:{kind}", "-o", str(partial), "--size", str(size), "--spp", str(spp),
             *directions, "-q"])
        partial.rename(path)
    return path
