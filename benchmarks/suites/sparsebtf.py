"""sparsebtf: SparseBTF (Kavoosighafi et al. 2024) against PCA at equal bytes on a generated BTF (no measured BTF
could be obtained), through `neumat fit-many`."""
from __future__ import annotations

import fcntl
import hashlib
from pathlib import Path
from typing import Callable

from neumat.reflectance import btf_generate, procedural_texture

from .. import harness
from .common import cli, fit_many, quality_rows

NAME = "sparsebtf"
DESCRIPTION = "SparseBTF against PCA at equal bytes on generated procedural BTFs, through fit-many"
#: its fits are independent jobs (--workers / --shard share them out; the BTFs they need made once, locked)
SHARDS = True
BUDGET = {
    "quick": {"ours": "one procedural BTF (bumps) at 20^2 texels, 17 x 17 directions (rings:3x30), 1 spp, both models at their recipes, SparseBTF with 2 dictionaries and 2 training steps",
              "paper": "dictionary training on 10 UBO2014 BTFs, tested on the others", "expected_wall": "about 60 s"},
    "full": {"ours": "the five procedural classes at 40^2 texels, 4 spp, both models at their recipes, seeds 0 and 1",
             "paper": "dictionary training on 10 UBO2014 BTFs, tested on the others (not available to us)",
             "expected_wall": "about 4 h one job after another (measured: each BTF's generation 16-20 min, each "
                              "SparseBTF fit 8-14 min, each PCA 25 s, on a loaded core); --workers 2: about half"},
}
CLASSES = ("bumps", "weave", "bricks", "dents", "ridges")


def run(run: harness.Run) -> None:
    """Generate the BTFs, fit both models and tabulate."""
    classes, size, spp = (CLASSES[:1], 20, 1) if run.quick else (CLASSES, 40, 4)
    directions = ["--directions", "rings:3x30"] if run.quick else []  # hemi151 (the full runs') is 64x the data
    with run.folder("btf-generate", classes, size, spp, directions) as folder:
        made = {str(folder / f"{kind}.nbtf"): _maker(folder, kind, size, spp, directions) for kind in classes}
        quick = ["--set", "sparse-btf:num_dictionaries=2", "--set", "sparse-btf:steps=2", "--n-configs", "4096"]
        options = (quick if run.quick else ["--n-configs", str(2 ** 18)]) + ["--image-spp", "0"]
        rows = fit_many(run, list(made), ["sparse-btf", "pca-btf"], options,
                        [run.seed] if run.quick else [run.seed, run.seed + 1], made=made)
    run.table("fits", "Generated BTFs x models (bytes: each model's own at fp16, SparseBTF's with its dictionary "
                      "ensemble, which BTFs would share; PCA keeps the most components that fit SparseBTF's per-BTF "
                      "bytes, the pca-btf default: the paper's comparison at equal storage)", quality_rows(rows))


def _maker(folder: Path, kind: str, size: int, spp: int, directions: list[str]) -> tuple[str, Callable[[], None]]:
    """(what makes folder/<kind>.nbtf: the generator's command and the hash of its code, a ledger key's part; a
    function that generates it unless a finished one is there). Shards sharing the folder (--workers) take a lock
    per file: one generates, another waiting for it then finds it made."""
    path = folder / f"{kind}.nbtf"
    args = ["data", "btf-generate", f"procedural:{kind}", "--size", str(size), "--spp", str(spp), *directions]
    code = hashlib.sha256(b"".join(Path(m.__file__).read_bytes()
                                   for m in (btf_generate, procedural_texture))).hexdigest()

    def make() -> None:
        with open(folder / f"{kind}.lock", "w") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            if not path.exists():
                partial = folder / f"{kind}.partial.nbtf"
                cli([*args[:3], "-o", str(partial), *args[3:], "-q"])
                partial.rename(path)

    return f"{' '.join(args)} (code {code[:16]})", make
