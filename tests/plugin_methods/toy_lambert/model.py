"""f(wi, wo) = albedo / pi above the horizon, albedo = exp(log_albedo) per channel."""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import nn

from neumat.core.config import resolve_config
from neumat.core.material import upper_hemisphere
from neumat.core.query import Query
from neumat.models.base import LearnedMaterial
from neumat.nn.codebook import float_bits, storage_bytes


@dataclass
class Config:
    """Toy Lambert hyper-parameters."""

    albedo: float = 0.5
    """Initial albedo of every channel."""


class ToyLambert(LearnedMaterial):
    """A Lambertian lobe with a learned RGB albedo."""

    name = "toy-lambert"
    paper = "test-only method (tests/plugin_methods)"
    source_kinds = ("brdf",)
    can_sample = False
    Config = Config

    def __init__(self, config: Config | None = None, **kwargs) -> None:
        nn.Module.__init__(self)
        self.cfg = resolve_config(Config, config, kwargs, "ToyLambert")
        self.log_albedo = nn.Parameter(torch.full((3,), math.log(self.cfg.albedo)))

    @property
    def config(self) -> Config:
        return self.cfg

    def eval(self, q: Query) -> torch.Tensor:
        """albedo / pi, 0 below the horizon."""
        f = (self.log_albedo.exp() / math.pi).to(q.dtype).expand(len(q), 3)
        return torch.where(upper_hemisphere(q.wi, q.wo).unsqueeze(-1), f, torch.zeros_like(f))

    def forward(self, q: Query) -> torch.Tensor:
        return self.eval(q)

    def size_bytes(self, precision: str = "fp16") -> int:
        return storage_bytes(3 * float_bits(precision))

    def flops(self) -> int:
        return 3
