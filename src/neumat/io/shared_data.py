"""Where the project's reference data (`shared/data`: RGL BRDFs, texture sets, environment maps) lives.

The data is not shipped with the package. It is looked up in `$NEUMAT_SHARED_DATA`, then in `../shared/data`
beside the source checkout (an editable install), then in `../shared/data` from the working directory (an
installed wheel run from the checkout, as the README's commands are). Set `NEUMAT_SHARED_DATA` to use it from
anywhere.
"""
from __future__ import annotations

import os
from pathlib import Path

#: the checkout-relative default: <repo>/../shared/data
CHECKOUT_DATA = Path(__file__).resolve().parents[4] / "shared" / "data"


def shared_data_candidates() -> list[Path]:
    """The folders looked in, in order (for messages that say where the data was not found)."""
    env = os.environ.get("NEUMAT_SHARED_DATA")
    found = ([Path(env)] if env else []) + [CHECKOUT_DATA, Path.cwd().parent / "shared" / "data"]
    return list(dict.fromkeys(p.resolve() for p in found))


def shared_data_dir() -> Path | None:
    """The reference data folder, or None when it is absent."""
    for candidate in shared_data_candidates():
        if candidate.is_dir():
            return candidate
    return None
