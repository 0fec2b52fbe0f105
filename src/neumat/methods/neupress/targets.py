"""Pieces of NeuPreSS training (TG et al., Sec. 4.2) that its recipe (`neumat.methods.neupress.train`) uses: the
appearance module as a function of observations (fitted by L2, Eq. 6), the grid of light directions and the KL
divergence that trains the importance sampling module against the appearance module's binned output (its own
inference data: no new path tracing). Training runs through `neumat.fit.trainer.fit`."""
from __future__ import annotations

import math

import torch

from neumat.core.coords import spherical_to_dir
from neumat.core.tensors import by_rows
from neumat.methods.neupress.model import NeuPreSS
from neumat.warp.azimuthal_gaussian import azimuthal_gaussian_pdf


def neupress_predict(model: NeuPreSS):
    """The unclamped appearance module as a function of observations (what the appearance phase fits)."""
    return lambda o: model.raw(o.wi, o.x, o.wo)


def light_grid(n_theta: int, n_phi: int, dtype=torch.float32) -> tuple[torch.Tensor, torch.Tensor]:
    """Bin centres (n_theta * n_phi, 3) of a uniform grid in spherical coordinates over the sphere and
    their solid angles (n_theta * n_phi,) (summing to 4 pi)."""
    theta_edges = torch.linspace(0, math.pi, n_theta + 1, dtype=torch.float64)
    theta = (theta_edges[:-1] + theta_edges[1:]) / 2
    phi = (torch.arange(n_phi, dtype=torch.float64) + 0.5) * (2 * math.pi / n_phi)
    t, p = torch.meshgrid(theta, phi, indexing="ij")
    w = spherical_to_dir(t.reshape(-1), p.reshape(-1))
    band = (torch.cos(theta_edges[:-1]) - torch.cos(theta_edges[1:])) * (2 * math.pi / n_phi)
    return w.to(dtype), band.repeat_interleave(n_phi).to(dtype)


#: rows of the frozen appearance module evaluated at once for the KL's target, so that its layers' activations stay
#: in cache (about half the sampler phase's time: NOTES.md, `neumat.methods.neupress.train`)
TARGET_ROWS = 4096


def sampler_kl(model: NeuPreSS, x: torch.Tensor, wo: torch.Tensor, n: torch.Tensor,
               grid: tuple[torch.Tensor, torch.Tensor]) -> torch.Tensor:
    """Mean over the B points (x, wo, n) (B, 3) of KL(target || lobe) on the light-direction bins `grid`:
    target proportional to the RGB mean of S_hat times the bin's solid angle, lobe to the Gaussian pdf
    times the solid angle, both normalised over the bins."""
    w, area = grid
    b, k = x.shape[0], w.shape[0]
    with torch.no_grad():
        f = by_rows(model.raw, TARGET_ROWS, w.repeat(b, 1), x.repeat_interleave(k, 0), wo.repeat_interleave(k, 0))
        target = f.clamp(min=0).mean(-1).reshape(b, k) * area
        keep = target.sum(-1) > 0
        target = target / target.sum(-1, keepdim=True).clamp(min=1e-30)
    sigma = model.sigma(x, wo)
    pdf = azimuthal_gaussian_pdf(w.repeat(b, 1), n.repeat_interleave(k, 0), sigma.repeat_interleave(k, 0)).reshape(b, k)
    lobe = pdf * area
    lobe = lobe / lobe.sum(-1, keepdim=True)
    kl = (target * (torch.log(target.clamp(min=1e-30)) - torch.log(lobe.clamp(min=1e-30)))).sum(-1)
    return (kl * keep).sum() / keep.sum().clamp(min=1)
