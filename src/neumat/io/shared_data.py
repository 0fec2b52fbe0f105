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


#: the documented examples (docs/examples in a checkout links here), shipped in the wheel
EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def resolve_data_path(text: str | Path) -> Path:
    """`text` as a path: itself when it exists or is absolute, else docs/examples/NAME from the shipped
    examples, else a path inside the reference data folder (`rgl/x.bsdf`, or `../shared/data/rgl/x.bsdf` run
    from elsewhere), else itself (for the caller's "does not exist"). So the README's commands run from an
    installed wheel too."""
    path = Path(text)
    if path.exists() or path.is_absolute():
        return path
    parts = path.parts
    if parts[:2] == ("docs", "examples") and (EXAMPLES.joinpath(*parts[2:])).exists():
        return EXAMPLES.joinpath(*parts[2:])
    inside = parts[3:] if parts[:3] == ("..", "shared", "data") else parts
    data = shared_data_dir()
    if data is not None and inside and data.joinpath(*inside).exists():
        return data.joinpath(*inside)
    return path
