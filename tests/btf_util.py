"""Small synthetic BTFs shared by the BTF tests."""
from __future__ import annotations

import torch

from neumat.reflectance.btf import TabulatedBTF, direction_set

#: directions and texels a side of the default synthetic BTF
N_DIRS = 9
SIZE = 8


def synthetic_btf(seed: int, dirs: torch.Tensor | None = None, size: int = SIZE) -> TabulatedBTF:
    """A positive BTF: spatially varying albedo and Phong-like lobe with a spatially varying exponent."""
    g = torch.Generator().manual_seed(seed)
    d = direction_set(N_DIRS) if dirs is None else dirs
    albedo = 0.2 + 0.6 * torch.rand(size, size, 3, generator=g)
    shininess = 2 + 30 * torch.rand(size, size, generator=g)
    r = d * torch.tensor([-1.0, -1.0, 1.0])
    cos = (r @ d.T).clamp(min=0)                                         # (L, V) mirror alignment
    lobe = cos[:, :, None, None] ** shininess                             # (L, V, H, W)
    data = albedo / 3.1416 + lobe[..., None] * torch.tensor([0.5, 0.45, 0.4])
    return TabulatedBTF(data, d, d, label=f"synthetic{seed}")
