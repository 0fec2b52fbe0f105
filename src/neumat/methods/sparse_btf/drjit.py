"""Dr.Jit runtime translator of SparseBTF (program "sparse-btf", `neumat.export.drjit.sparse_btf`): the sparse
codes, the dictionary ensembles, the standardisation statistics and the BTF's direction bins, as stored."""
from __future__ import annotations

import numpy as np
import torch

from neumat.core.errors import InputError
from neumat.methods.sparse_btf.model import SparseBTF


def _np(t: torch.Tensor, dtype=np.float32) -> np.ndarray:
    return t.detach().cpu().numpy().astype(dtype)


@torch.no_grad()
def translate(model: SparseBTF) -> tuple[dict, dict]:
    """(manifest, arrays) of a SparseBTF, either angular interpolation (the manifest's "angular": "coefficient", the
    paper's Eq. 6, or "value"); InputError for a subclass that evaluates differently."""
    if not isinstance(model, SparseBTF) or type(model)._eval_batch is not SparseBTF._eval_batch:
        raise InputError(f"sparse-btf drjit translator: expected a SparseBTF, got {type(model).__name__}")
    c = model.cfg
    arrays = {f"dict_{n}": _np(getattr(model, f"dict_{n}")) for n in range(1, 5)}
    arrays.update(values=_np(model.values), index=_np(model.index, np.int32),
                  membership=_np(model.membership, np.int32), counts=_np(model.counts, np.int32),
                  mean=_np(model.mean), std=_np(model.std), light_dirs=_np(model.light_dirs),
                  view_dirs=_np(model.view_dirs))
    manifest = {"program": "sparse-btf", "patch": c.patch, "num_dictionaries": c.num_dictionaries,
                "n_light": c.n_light, "n_view": c.n_view, "height": c.height, "width": c.width,
                "log_eps": c.log_eps, "neighbours": c.neighbours, "angular": c.angular,
                "describe": f"sparse-btf ({c.height}x{c.width} texels, patch {c.patch}, {c.num_dictionaries} "
                            f"dictionaries, {c.n_light}x{c.n_view} directions, tau {tuple(c.tau)}, angular "
                            f"{c.angular})"}
    return manifest, arrays
