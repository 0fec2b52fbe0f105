"""Write an output file all at once: into a temporary file beside it, then renamed over it. A failure leaves
neither a partial output nor the temporary file, and an existing output stays as it was."""
from __future__ import annotations

import os
from pathlib import Path
from typing import Callable

from ..core.errors import InputError


def atomic_write(path: str | Path, write: Callable[[str], object]) -> Path:
    """Call `write(tmp)` to write the file's content to `tmp` (a path string in `path`'s folder), then move
    it to `path` with the usual permissions (0666 less the umask, 0644 by default); missing parent folders are
    created (as image outputs create them). Raises InputError when `path` is a folder; any error of `write`
    is re-raised after the temporary file is removed."""
    path = Path(path)
    if path.is_dir():
        raise InputError(f"output {str(path)!r} is a folder; expected a file path")
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        write(str(tmp))
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask
