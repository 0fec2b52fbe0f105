"""The entries of a tabulated BTF as queries: every texel centre x every (light, view) pair of its direction
sets, for fitting any spatially varying model to exactly the tabulated values (`table_samples` of the fit
package's measured_samples.py) and for decoding such a model back into a table of the same layout (to
compare it entry by entry with the BTF, like SparseBTF and PCA).

Entry order: the flattened (L, V, H, W) index of `TabulatedBTF.data`; texel (row i, col j) at its centre
uv = ((j + 0.5) / W, 1 - (i + 0.5) / H) (`neumat.reflectance.btf`).
"""
from __future__ import annotations

import torch

from ..core.errors import InputError
from ..core.material import Material
from ..core.query import Query
from ..reflectance.btf import TabulatedBTF


def texel_centre_uv(height: int, width: int, dtype=torch.float32, device=None) -> torch.Tensor:
    """uv (H * W, 2) of the texel centres, row-major (row 0, the top, first)."""
    if height < 1 or width < 1:
        raise InputError(f"texel_centre_uv: expected height, width >= 1, got {height} x {width}")
    rows, cols = torch.meshgrid(torch.arange(height, device=device), torch.arange(width, device=device),
                                indexing="ij")
    uv = torch.stack([(cols.reshape(-1) + 0.5) / width, 1 - (rows.reshape(-1) + 0.5) / height], -1)
    return uv.to(dtype)


def table_queries(btf: TabulatedBTF, start: int = 0, stop: int | None = None) -> Query:
    """Queries (N, .) of the table entries start .. stop - 1 (default: all L V H W of them), in entry order."""
    l, v, h, w = btf.shape
    total = l * v * h * w
    stop = total if stop is None else stop
    if not 0 <= start <= stop <= total:
        raise InputError(f"table_queries: expected 0 <= start <= stop <= {total} entries, got {start} .. {stop}")
    index = torch.arange(start, stop, device=btf.light_dirs.device)
    texel, view, light = index % (h * w), index // (h * w) % v, index // (v * h * w)
    uv = texel_centre_uv(h, w, device=index.device)[texel]
    return Query(btf.light_dirs[light], btf.view_dirs[view], uv=uv)


@torch.no_grad()
def decode_table(model: Material, like: TabulatedBTF, batch: int = 1 << 16) -> TabulatedBTF:
    """`model` evaluated at every entry of `like` (texel centres x its direction pairs), as a TabulatedBTF
    of the same shape and directions (float32), in batches of `batch` queries."""
    if batch < 1:
        raise InputError(f"decode_table batch: expected >= 1, got {batch}")
    l, v, h, w = like.shape
    total = l * v * h * w
    parts = [model.eval(table_queries(like, s, min(s + batch, total))).float() for s in range(0, total, batch)]
    data = torch.cat(parts).reshape(l, v, h, w, 3).to(like.data.device)
    return TabulatedBTF(data, like.light_dirs, like.view_dirs, like.neighbours, label=f"decoded {like.label}")


__all__ = ["decode_table", "table_queries", "texel_centre_uv"]
