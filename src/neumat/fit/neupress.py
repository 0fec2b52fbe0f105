"""Training NeuPreSS (TG et al., Sec. 4.2): the appearance module by L2 on path-traced observations (Eq. 6),
then the importance sampling module by a KL divergence against the appearance module's output binned over
a 32 x 64 grid of light directions (its own inference data: no new path tracing)."""
from __future__ import annotations

import math

import torch

from ..core.checks import check_int
from ..core.coords import spherical_to_dir
from ..models.neupress import NeuPreSS
from ..warp.azimuthal_gaussian import azimuthal_gaussian_pdf
from .adam_steps import adam_steps
from .translucent_fit import fit_observations
from .translucent_observations import Observations


def fit_neupress(model: NeuPreSS, observations: Observations, steps: int = 4000, batch: int = 4096,
                 lr: float = 1e-3, bounds: tuple[torch.Tensor, torch.Tensor] | None = None, seed: int = 0,
                 progress: bool = False, log_every: int = 100,
                 validation: Observations | None = None) -> list[dict]:
    """Fit the appearance module by mean squared error on random batches of `observations` (Adam, `lr`
    halved at 50% and 75% of `steps`). `bounds` (lo, hi) is the object's bounding box (default: that of
    the observed points). With `validation` (held-back observations, the paper keeps 5%), every record also
    holds "validation_mse" and the model ends with the weights of the record where that was lowest (early
    stopping: noisy path-traced targets are otherwise learnt by heart). Returns the loss history of
    `adam_steps`."""
    lo, hi = bounds if bounds is not None else (observations.x.min(0).values, observations.x.max(0).values)
    model.set_bounds(lo, hi)
    params = [p for name, p in model.named_parameters() if name.startswith("appearance")]
    return fit_observations(neupress_predict(model), params, observations, steps, batch, lr, seed, progress,
                            log_every, validation, "NeuPreSS appearance")


def neupress_predict(model: NeuPreSS):
    """The unclamped appearance module as a function of observations (what `fit_neupress` fits)."""
    return lambda o: model.raw(o.wi, o.x, o.wo)


def light_grid(n_theta: int = 32, n_phi: int = 64, dtype=torch.float32) -> tuple[torch.Tensor, torch.Tensor]:
    """Bin centres (n_theta * n_phi, 3) of a uniform grid in spherical coordinates over the sphere and
    their solid angles (n_theta * n_phi,) (summing to 4 pi)."""
    theta_edges = torch.linspace(0, math.pi, n_theta + 1, dtype=torch.float64)
    theta = (theta_edges[:-1] + theta_edges[1:]) / 2
    phi = (torch.arange(n_phi, dtype=torch.float64) + 0.5) * (2 * math.pi / n_phi)
    t, p = torch.meshgrid(theta, phi, indexing="ij")
    w = spherical_to_dir(t.reshape(-1), p.reshape(-1))
    band = (torch.cos(theta_edges[:-1]) - torch.cos(theta_edges[1:])) * (2 * math.pi / n_phi)
    return w.to(dtype), band.repeat_interleave(n_phi).to(dtype)


def sampler_kl(model: NeuPreSS, x: torch.Tensor, wo: torch.Tensor, n: torch.Tensor,
               grid: tuple[torch.Tensor, torch.Tensor]) -> torch.Tensor:
    """Mean over the B points (x, wo, n) (B, 3) of KL(target || lobe) on the light-direction bins `grid`:
    target proportional to the RGB mean of S_hat times the bin's solid angle, lobe to the Gaussian pdf
    times the solid angle, both normalised over the bins."""
    w, area = grid
    b, k = x.shape[0], w.shape[0]
    with torch.no_grad():
        f = model.raw(w.repeat(b, 1), x.repeat_interleave(k, 0), wo.repeat_interleave(k, 0))
        target = f.clamp(min=0).mean(-1).reshape(b, k) * area
        keep = target.sum(-1) > 0
        target = target / target.sum(-1, keepdim=True).clamp(min=1e-30)
    sigma = model.sigma(x, wo)
    pdf = azimuthal_gaussian_pdf(w.repeat(b, 1), n.repeat_interleave(k, 0), sigma.repeat_interleave(k, 0)).reshape(b, k)
    lobe = pdf * area
    lobe = lobe / lobe.sum(-1, keepdim=True)
    kl = (target * (torch.log(target.clamp(min=1e-30)) - torch.log(lobe.clamp(min=1e-30)))).sum(-1)
    return (kl * keep).sum() / keep.sum().clamp(min=1)


def fit_neupress_sampler(model: NeuPreSS, observations: Observations, steps: int = 1000, batch: int = 32,
                         lr: float = 1e-3, grid: tuple[int, int] = (32, 64), seed: int = 0,
                         progress: bool = False, log_every: int = 100) -> list[dict]:
    """Fit the importance sampling module by `sampler_kl` on random (x, wo, n) of `observations`."""
    _check_steps(steps, batch)
    g = light_grid(*grid)
    gen = torch.Generator().manual_seed(seed)
    obs = observations

    def step():
        idx = torch.randint(len(obs), (batch,), generator=gen)
        return (sampler_kl(model, obs.x[idx], obs.wo[idx], obs.n[idx], g),)

    params = [p for name, p in model.named_parameters() if name.startswith("sampler")]
    return adam_steps(params, steps, lr, step, ["kl"], "NeuPreSS sampler", log_every, progress)


def _check_steps(steps: int, batch: int) -> None:
    for name, v in (("steps", steps), ("batch", batch)):
        check_int(v, f"NeuPreSS fit {name}")
