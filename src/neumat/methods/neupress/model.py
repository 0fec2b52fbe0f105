"""NeuPreSS (TG, Frisvad, Ramamoorthi, Jensen): neural precomputed subsurface scattering of a whole
translucent object under distant light.

Appearance specification module (Sec. 4.1): S_hat(wi; x, wo) = SkipMLP(F(v)) with the 7-vector
v = (theta_i, phi_i, theta_o, phi_o, x, y, z) of object-space spherical angles and position, Fourier
features F (Eq. 8: 256 rows of G ~ N(18, 1); our default N(0, 0.3^2), see Config), 7 ReLU layers of 128 with skip
connections between alternate layers, linear RGB output trained with L2 (Eq. 6). Importance sampling module: the same
kind of features of the 5-vector (x, y, z, theta_o, phi_o), a ReLU MLP 512-128-32 and a standard deviation
sigma of a Gaussian lobe in the azimuthal equidistant projection around the surface normal n_o
(Sec. 3.2), trained with a KL divergence against the appearance module's binned output (Sec. 4.2).

Inputs are scaled to [0, 1] before the features (angles by pi and 2 pi, positions by the object's
bounding box, stored with the model); the paper does not say how it scales them. The paper's sampler MLP
ends at 32 outputs; here a linear head maps them to log sigma (sigma in [SIGMA_MIN, SIGMA_MAX]).
`eval` clamps the output at 0 (radiance cannot be negative); training uses the raw output.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import nn

from neumat.core.checks import check_int
from neumat.core.config import resolve_config
from neumat.core.coords import dir_to_spherical
from neumat.core.errors import InputError
from neumat.core.material import check_sample_u
from neumat.core.query import Query
from neumat.core.tensors import by_rows
from neumat.nn import cpu_kernels
from neumat.models.base import LearnedMaterial
from neumat.nn.codebook import float_bits, storage_bytes
from neumat.nn.fourier import FourierFeatures
from neumat.nn.skip_mlp import SkipMLP
from neumat.warp.azimuthal_gaussian import AzimuthalGaussianLobe

SIGMA_MIN, SIGMA_MAX = 0.02, 20.0
DIRECTION_ENCODINGS = ("spherical", "cartesian")


@dataclass
class Config:
    """NeuPreSS hyper-parameters; defaults are the paper's (Sec. 4.1) except the Fourier scale of G.

    G ~ N(0, 0.3^2) instead of the paper's N(18, 1): at the few paths per observation a workstation traces,
    N(18, 1) learns the noise (src/neumat/methods/neupress/NOTES.md, "Config: the Fourier scale"). `feature_mean=18,
    feature_std=1` gives the paper's."""

    features: int = 256
    """Rows of the Fourier matrix G (the feature vector has twice as many entries)."""
    feature_mean: float = 0.0
    """Mean of the entries of G (the paper: "sufficiently large to get a positive matrix", 18; see above)."""
    feature_std: float = 0.3
    """Standard deviation of the entries of G (the paper: 1; small values generalise from few, noisy
    observations, see above)."""
    width: int = 128
    """Neurons per layer of the appearance module."""
    layers: int = 7
    """Layers of the appearance module (the paper: 5 to 11; 7 in its ablation reference)."""
    skips: bool = True
    """Skip connections between alternate layers of the appearance module (the paper's; False for its Fig. 7
    ablation: the same layers without the additions)."""
    sampler_hidden: tuple[int, ...] = (512, 128, 32)
    """Hidden layers of the importance sampling module."""
    direction_encoding: str = "spherical"
    """"spherical" (theta / pi, phi / 2 pi: the paper's 7-vector) or "cartesian" (unit vectors, 9-vector)."""
    seed: int = 0
    """Seed of the Fourier matrices."""


def _check_config(c: Config) -> None:
    for name in ("features", "width", "layers"):
        check_int(getattr(c, name), f"NeuPreSS.{name}")
    if not isinstance(c.skips, bool):
        raise InputError(f"NeuPreSS.skips: expected True or False, got {c.skips!r}")
    if not c.sampler_hidden or any(isinstance(h, bool) or not isinstance(h, int) or h < 1 for h in c.sampler_hidden):
        raise InputError(f"NeuPreSS.sampler_hidden: expected positive integers, got {c.sampler_hidden!r}")
    if c.direction_encoding not in DIRECTION_ENCODINGS:
        raise InputError(f"NeuPreSS.direction_encoding: expected one of {DIRECTION_ENCODINGS}, "
                         f"got {c.direction_encoding!r}")


class NeuPreSS(LearnedMaterial):
    """S_hat(wi; x, wo) of one translucent object (see the module docstring). Queries need x, wo (and n to
    sample); directions are object space and span the whole sphere."""

    name = "neupress"
    paper = "NeuPreSS (TG, Frisvad, Ramamoorthi, Jensen): neural precomputed subsurface scattering"
    source_kinds = ("translucent",)
    full_sphere = True
    can_sample = False  # it samples the light direction wi given (x, wo, n): see `sample_incident`
    Config = Config
    #: rows per slice of an evaluation: the default network's activations of 512 rows stay in cache (one thread,
    #: 2^16 queries: 1.3e5 evaluations per CPU second unsliced; slices of 256 / 512 / 1024 / 2048: 2.8e5 / 3.4e5 /
    #: 2.6e5-3.4e5 / 2.5e5; 2^10 queries: 2.3e5-3.3e5 at any slice, as noisy)
    eval_chunk = 512

    def __init__(self, config: Config | None = None, **kwargs) -> None:
        nn.Module.__init__(self)
        cfg = resolve_config(Config, config, kwargs, "NeuPreSS")
        if isinstance(cfg.sampler_hidden, list):
            cfg.sampler_hidden = tuple(cfg.sampler_hidden)
        _check_config(cfg)
        self.cfg = cfg
        d = 2 if cfg.direction_encoding == "spherical" else 3
        self.appearance_features = FourierFeatures(2 * d + 3, cfg.features, cfg.feature_mean, cfg.feature_std,
                                                   seed=cfg.seed)
        self.appearance = SkipMLP(self.appearance_features.out_dim, cfg.width, cfg.layers, 3, skips=cfg.skips)
        self.sampler_features = FourierFeatures(d + 3, cfg.features, cfg.feature_mean, cfg.feature_std,
                                                seed=cfg.seed + 1)
        dims = [self.sampler_features.out_dim, *cfg.sampler_hidden]
        layers: list[nn.Module] = []
        for a, b in zip(dims[:-1], dims[1:]):
            layers += [nn.Linear(a, b), nn.ReLU()]
        self.sampler = nn.Sequential(*layers, nn.Linear(dims[-1], 1))
        self.register_buffer("box_min", torch.zeros(3))
        self.register_buffer("box_max", torch.ones(3))

    @property
    def config(self) -> Config:
        return self.cfg

    def set_bounds(self, lo: torch.Tensor, hi: torch.Tensor) -> None:
        """Object-space bounding box (3,), (3,) that maps positions to [0, 1]^3 before the features."""
        lo, hi = torch.as_tensor(lo, dtype=torch.float32), torch.as_tensor(hi, dtype=torch.float32)
        if lo.shape != (3,) or hi.shape != (3,) or not bool((hi > lo).all()):
            raise InputError(f"NeuPreSS.set_bounds: expected lo < hi of shape (3,), got {lo.tolist()}, {hi.tolist()}")
        self.box_min.copy_(lo)
        self.box_max.copy_(hi)

    # ---- encoding -------------------------------------------------------------------------------------------
    def _direction(self, w: torch.Tensor) -> torch.Tensor:
        if self.cfg.direction_encoding == "cartesian":
            return w
        theta, phi = dir_to_spherical(w)
        return torch.stack([theta / math.pi, phi / (2 * math.pi)], -1)

    def _position(self, x: torch.Tensor) -> torch.Tensor:
        return (x - self.box_min) / (self.box_max - self.box_min)

    def raw(self, wi: torch.Tensor, x: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
        """Unclamped network output (N, 3) for object-space wi, x, wo (N, 3) (what training fits)."""
        dtype = self.box_min.dtype
        v = torch.cat([self._direction(wi.to(dtype)), self._direction(wo.to(dtype)), self._position(x.to(dtype))], -1)
        return self.appearance(self.appearance_features(v))

    def eval(self, q: Query) -> torch.Tensor:
        """S_hat(q.wi; q.x, q.wo), (N, 3) linear RGB per steradian, clamped at 0."""
        q.require("x", "wo", who="NeuPreSS.eval")
        if len(q) <= cpu_kernels.NEUPRESS_ROWS and cpu_kernels.usable(q.wi, q.x, q.wo, self.box_min,
                                                                      owner=self.appearance):
            return cpu_kernels.neupress_rows(self, q.wi, q.x, q.wo)  # the same within float32 rounding
        return by_rows(lambda rows: torch.relu(self.raw(rows.wi, rows.x, rows.wo)).to(q.dtype), self.eval_chunk, q)

    def forward(self, q: Query) -> torch.Tensor:
        return self.eval(q)

    # ---- importance sampling of the light direction ---------------------------------------------------------
    def sigma(self, x: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
        """Standard deviation (N,) in radians of the sampling lobe around the normal at x for view wo."""
        dtype = self.box_min.dtype
        v = torch.cat([self._position(x.to(dtype)), self._direction(wo.to(dtype))], -1)
        log_sigma = self.sampler(self.sampler_features(v)).squeeze(-1)
        return torch.exp(log_sigma.clamp(math.log(SIGMA_MIN), math.log(SIGMA_MAX)))

    def incident_lobe(self, q: Query) -> AzimuthalGaussianLobe:
        """The Gaussian sampling lobe around q.n (sigma from the sampler network, evaluated once), for drawing light
        directions and for their densities. q needs x, wo and n; q.wi is ignored."""
        q.require("x", "wo", "n", who="NeuPreSS.incident_lobe")
        return AzimuthalGaussianLobe(q.n, self.sigma(q.x, q.wo).to(q.dtype))

    def sample_incident(self, q: Query, u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Light directions wi (N, 3) drawn from the Gaussian lobe around q.n, and their solid-angle pdf (N,).

        q needs x, wo and n; u (N, 2) uniform in [0, 1). q.wi is ignored."""
        q.require("x", "wo", "n", who="NeuPreSS.sample_incident")
        u = check_sample_u(q, u)
        return self.incident_lobe(q).sample(u.to(q.dtype))

    def incident_pdf(self, q: Query) -> torch.Tensor:
        """Solid-angle density (N,) with which `sample_incident` draws q.wi."""
        q.require("x", "wo", "n", who="NeuPreSS.incident_pdf")
        return self.incident_lobe(q).pdf(q.wi)

    # ---- size ----------------------------------------------------------------------------------------------
    def size_bytes(self, precision: str = "fp16", sampler: bool = True) -> int:
        """Weights of the appearance module (and the sampler) at `precision`, plus the bounding box (6 float32).
        The Fourier matrices are not counted: they are regenerated from the seed."""
        n = self.appearance.num_parameters()
        if sampler:
            n += sum(p.numel() for p in self.sampler.parameters())
        return storage_bytes(n * float_bits(precision) + 6 * 32)

    def flops(self) -> int:
        """Floating-point operations of one appearance evaluation (features + MLP)."""
        return self.appearance_features.flops() + self.appearance.flops()
