"""The named suites: name -> module. Each module defines NAME, DESCRIPTION, BUDGET ({"quick"|"full": {"ours",
"paper", "expected_wall"}}) and run(run: benchmarks.harness.Run), imported only when asked for; SHARDS = True where
its work is independent fit jobs (`harness.Run.job`) that --workers / --shard may share out."""
from __future__ import annotations

import importlib

SUITES = ("speed", "cuda", "neubrdf", "multiscale", "neural-appearance", "neupress", "sparsebtf", "export-parity")


def load(name: str):
    """The module of suite `name` (ValueError naming the suites for an unknown name)."""
    if name not in SUITES:
        raise ValueError(f"unknown suite {name!r}; suites: {', '.join(SUITES)}")
    return importlib.import_module(f"{__name__}.{name.replace('-', '_')}")
