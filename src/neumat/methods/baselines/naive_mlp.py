"""Naive MLP baseline: a plain MLP on the concatenated directions, f(wi, wo) = exp(m([wi, wo])).

No grid, no codebook, no reparametrisation: the reference point that shows what the NeuBRDF feature
grids (and the NBRDF half / difference input) buy. Not from a paper; the default size (3 x 64) is a
tiny-MLP budget comparable to NeuBRDF's decoder.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from neumat.core.checks import check_int
from neumat.core.config import resolve_config
from neumat.core.material import zero_below_horizon
from neumat.core.query import Query
from neumat.core.tensors import by_rows
from neumat.models.base import LearnedMaterial
from neumat.nn import cpu_kernels
from neumat.nn.codebook import float_bits, storage_bytes
from neumat.nn.mlp import MLP


@dataclass
class Config:
    """Naive MLP hyper-parameters (no paper: a plain tiny MLP of NeuBRDF's decoder budget)."""

    hidden: int = 64
    """Neurons per hidden layer."""
    hidden_layers: int = 3
    """Number of hidden layers."""
    activation: str = "relu"
    """Hidden activation (a name of `neumat.nn.mlp.ACTIVATIONS`)."""


def _check_config(c: Config) -> None:
    for name, lo in (("hidden", 1), ("hidden_layers", 0)):
        check_int(getattr(c, name), f"NaiveMLP.{name}", lo)


class NaiveMLP(LearnedMaterial):
    """exp(MLP([wi, wo])) (6 inputs, local-frame Cartesian directions), 0 below the horizon.

    The exponential keeps the output positive and lets the MLP work in log space (as NeuBRDF).
    """

    name = "naive-mlp"
    paper = "plain MLP on (wi, wo): baseline of NeuBRDF (Dou, Zheng et al. 2024)"
    source_kinds = ("brdf",)
    can_sample = False
    Config = Config

    def __init__(self, config: Config | None = None, **kwargs) -> None:
        nn.Module.__init__(self)
        cfg = resolve_config(Config, config, kwargs, 'NaiveMLP')
        _check_config(cfg)
        self.cfg = cfg
        self.mlp = MLP(6, cfg.hidden, cfg.hidden_layers, 3, cfg.activation)

    @property
    def config(self) -> Config:
        return self.cfg

    def eval(self, q: Query) -> torch.Tensor:
        """BRDF value (N, 3), linear RGB, cosine excluded; 0 below the horizon."""
        q.require("wo", who="NaiveMLP.eval")
        if cpu_kernels.usable(q.wi, q.wo, self.mlp.net[0].weight):
            packed = cpu_kernels.prepared(self, lambda: cpu_kernels.PackedMLP.pack(self.mlp.net))
            if packed is not None:  # the MLP as one fused C call (neumat.nn.cpu_kernels), exp and horizon in torch
                return self._value(q, lambda x: cpu_kernels.mlp_forward(packed, x))
        return by_rows(lambda rows: self._value(rows, self.mlp), self.eval_chunk, q)

    def _value(self, q: Query, mlp) -> torch.Tensor:
        """exp(mlp([wi, wo])), 0 below the horizon, in q's dtype: mlp the module or its fused kernel."""
        dtype = self.mlp.linears()[0].weight.dtype
        f = torch.exp(mlp(torch.cat([q.wi, q.wo], -1).to(dtype)))
        f = zero_below_horizon(f, q.wi, q.wo)
        return f.to(q.dtype)

    def forward(self, q: Query) -> torch.Tensor:
        return self.eval(q)

    def size_bytes(self, precision: str = "fp16") -> int:
        """MLP weights and biases at `precision`."""
        return storage_bytes(self.mlp.num_parameters() * float_bits(precision))

    def flops(self) -> int:
        """MLP floating-point operations per evaluation (the output exp not counted, as for NeuBRDF)."""
        return self.mlp.flops()
