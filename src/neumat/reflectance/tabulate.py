"""Tabulate any Material to the MERL layout (the inverse of the `MerlMaterial` lookup)."""
from __future__ import annotations

import math

import numpy as np
import torch

from ..core.coords import rusinkiewicz_to_io
from ..core.errors import InputError
from ..core.material import Material
from ..core.query import Query
from ..io.merl import MERL_DIMS, MERL_SCALE

#: value stored where a cell centre has a direction below the surface (MERL's "missing" marker)
MISSING = -1.0


def merl_cell_centres(dtype=torch.float64, device=None) -> tuple[torch.Tensor, ...]:
    """Rusinkiewicz angles (theta_h, theta_d, phi_d), each (90 * 90 * 180,) in table order, of the cell
    centres: theta_h = ((i + 0.5) / 90)^2 pi / 2, theta_d = (j + 0.5) / 90 * pi / 2, phi_d = (k + 0.5) / 180 * pi."""
    n_h, n_d, n_p = MERL_DIMS
    kw = dict(dtype=dtype, device=device)
    th = ((torch.arange(n_h, **kw) + 0.5) / n_h) ** 2 * (math.pi / 2)
    td = (torch.arange(n_d, **kw) + 0.5) / n_d * (math.pi / 2)
    pd = (torch.arange(n_p, **kw) + 0.5) / n_p * math.pi
    grid = torch.meshgrid(th, td, pd, indexing="ij")
    return tuple(g.reshape(-1) for g in grid)


def tabulate_merl(material: Material, device: str | torch.device = "cpu", batch: int = 1 << 16,
                  dtype: torch.dtype = torch.float64, progress: bool = False) -> np.ndarray:
    """Unscaled MERL table (3, 90, 90, 180) float64 of `material`, sampled at the cell centres with
    phi_h = 0 and divided by the MERL scale factors, so that `MerlMaterial(table)` reproduces it.

    Negative material values (e.g. RGB conversion artefacts of measured data) are stored as 0, and cells
    whose centre puts wi or wo below the surface hold -1 (missing).
    """
    if not isinstance(material, Material):
        raise InputError(f"tabulate_merl material: expected a neumat Material, got {type(material).__name__}")
    if material.spatially_varying:
        raise InputError(f"tabulate_merl material: {material.describe()} is spatially varying; MERL is one BRDF")
    if batch < 1:
        raise InputError(f"tabulate_merl batch: expected a positive integer, got {batch}")
    th, td, pd = merl_cell_centres(dtype=dtype, device=device)
    out = torch.full((th.shape[0], 3), MISSING, dtype=torch.float64)
    starts = range(0, th.shape[0], batch)
    if progress:
        from rich.progress import track
        starts = track(starts, description="tabulating MERL")
    with torch.no_grad():
        for s in starts:
            sl = slice(s, s + batch)
            wi, wo = rusinkiewicz_to_io(th[sl], torch.zeros_like(th[sl]), td[sl], pd[sl])
            wi = wi / wi.norm(dim=-1, keepdim=True)
            wo = wo / wo.norm(dim=-1, keepdim=True)
            ok = (wi[:, 2] > 0) & (wo[:, 2] > 0)
            if bool(ok.any()):
                f = material.eval(Query(wi[ok], wo[ok]))
                idx = torch.arange(s, min(s + batch, th.shape[0]))[ok.cpu()]
                f = f.detach().to("cpu", torch.float64).clamp(min=0)
                out[idx] = f / torch.tensor(MERL_SCALE, dtype=torch.float64)
    return out.T.reshape(3, *MERL_DIMS).numpy()


def merl_table_mse(model: Material, reference: Material | np.ndarray, device: str | torch.device = "cpu",
                   batch: int = 1 << 16) -> float:
    """Mean squared error (sr^-2) of `model` against `reference` over the valid cells of the MERL table
    (both directions above the surface at the cell centre, phi_h = 0), all three channels: the "MSE on the raw
    data" of NeuBRDF's Table 4 and Fig. 8. Both are tabulated as `tabulate_merl` does (negatives as 0); the
    errors are in BRDF units (the table's values times the MERL scale factors). It weights the cells, not the
    sphere: MERL's theta_h = (i / 90)^2 pi / 2 puts 8 % of the cells within half a degree of the specular peak,
    so on shiny materials the peak dominates it. `reference` may be its `tabulate_merl` table already (scoring
    several models against one reference then tabulates it once)."""
    got = tabulate_merl(model, device=device, batch=batch)
    want = reference if isinstance(reference, np.ndarray) else tabulate_merl(reference, device=device, batch=batch)
    if want.shape != got.shape:
        raise InputError(f"merl_table_mse: a tabulated reference must be a MERL table of shape {got.shape}, "
                         f"got {want.shape}")
    valid = want[0] != MISSING
    scale = np.asarray(MERL_SCALE)[:, None]
    return float((((got[:, valid] - want[:, valid]) * scale) ** 2).mean())
