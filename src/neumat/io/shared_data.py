"""Where the project's reference data (`shared/data`: RGL BRDFs, texture sets, environment maps) lives.

The data is not shipped with the package. It is looked up in `$NEUMAT_SHARED_DATA`, then in
`../shared/data` beside the source checkout.
"""
from __future__ import annotations

import os
from pathlib import Path

#: the checkout-relative default: <repo>/../shared/data
CHECKOUT_DATA = Path(__file__).resolve().parents[4] / "shared" / "data"


def shared_data_dir() -> Path | None:
    """The reference data folder, or None when it is absent."""
    env = os.environ.get("NEUMAT_SHARED_DATA")
    for candidate in ([Path(env)] if env else []) + [CHECKOUT_DATA]:
        if candidate.is_dir():
            return candidate
    return None
