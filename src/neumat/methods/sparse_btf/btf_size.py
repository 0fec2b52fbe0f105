"""The size of a tabulated BTF as the BTF models' configs hold it (n_light, n_view, height, width): what
`SparseBTF` and `PCABTF` are built for (`for_btf`, their recipes' `config_for_source`) and check a source
against (`check_source`)."""
from __future__ import annotations

import torch

from neumat.core.errors import InputError

FIELDS = ("n_light", "n_view", "height", "width")


def btf_table_size(btf, who: str) -> dict[str, int]:
    """{"n_light", "n_view", "height", "width"} of a tabulated BTF (data (L, V, H, W, 3) and its directions);
    InputError naming `who` for anything else."""
    data = getattr(btf, "data", None)
    if not isinstance(data, torch.Tensor) or data.dim() != 5 or not hasattr(btf, "light_dirs"):
        raise InputError(f"{who}: the source must be one tabulated BTF (.nbtf, .btf; neumat.reflectance.btf.read_btf), "
                         f"got {type(btf).__name__}")
    return dict(zip(FIELDS, (int(n) for n in data.shape[:4])))


def check_btf_table_size(btf, cfg, who: str, builder: str) -> None:
    """InputError unless `btf` is a tabulated BTF of the size `cfg` was built for (`builder` names the call
    that builds a model for it)."""
    size = tuple(btf_table_size(btf, who).values())
    built = tuple(getattr(cfg, f) for f in FIELDS)
    if size != built:
        raise InputError(f"{who}: the BTF has {size} (lights, views, height, width) but the model was built for "
                         f"{built}; build it with {builder}(btf, ...)")
