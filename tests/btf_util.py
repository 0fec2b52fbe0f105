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


def non_reciprocal_btf(seed: int) -> TabulatedBTF:
    """`synthetic_btf(seed)` made non-reciprocal (light and view bins play different roles), so that mixing them up
    in an implementation shows."""
    btf = synthetic_btf(seed)
    btf.data = btf.data * (1 + 0.5 * btf.light_dirs[:, 0] + 0.3 * btf.light_dirs[:, 1])[:, None, None, None, None]
    return btf


def unambiguous(model, q, gap: float = 1e-5) -> torch.Tensor:
    """Queries whose k-th and (k+1)-th nearest light and view bins are not tied (float rounding could swap a tie
    between two implementations, and k-nearest interpolation jumps there)."""
    k = model.cfg.neighbours
    keep = torch.ones(len(q), dtype=torch.bool)
    for dirs, w in ((model.light_dirs, q.wi), (model.view_dirs, q.wo)):
        top = (w @ dirs.T).topk(k + 1, dim=-1).values
        keep &= (top[:, k - 1] - top[:, k]) > gap
    return keep


def assert_kernel_equals_torch(model, q) -> None:
    """model.eval(q) runs one fused kernel call (neumat.nn.cpu_kernels) and equals the torch path within relative
    1e-5 on the queries whose bins are not tied (`unambiguous`: more than half of them, and more than 10 of the first
    40, the rows placed on bins); 0 below the horizon."""
    from neumat.nn import cpu_kernels

    before = cpu_kernels.calls[0]
    fast = model.eval(q)
    assert cpu_kernels.calls[0] == before + 1
    with cpu_kernels.switched_off():
        ref = model.eval(q)
    below = (q.wi[:, 2] <= 0) | (q.wo[:, 2] <= 0)
    assert below.any() and (fast[below] == 0).all()
    keep = ~below & unambiguous(model, q)
    assert keep.float().mean() > 0.5 and keep[:40].sum() > 10  # ties of the k-th bin may pick either: skipped
    err = (fast - ref).abs()[keep] / ref.abs()[keep].clamp(min=1e-3)
    assert float(err.max()) < 1e-5, float(err.max())
