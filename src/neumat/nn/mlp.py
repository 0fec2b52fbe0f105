"""A tiny fully connected network with a FLOP count, for neural material decoders."""
from __future__ import annotations

import itertools

import torch
from torch import nn

from neumat.core.checks import check_int
from neumat.core.errors import InputError

ACTIVATIONS = {
    "relu": nn.ReLU,
    "leaky_relu": nn.LeakyReLU,
    "silu": nn.SiLU,
    "gelu": nn.GELU,
    "tanh": nn.Tanh,
    "sigmoid": nn.Sigmoid,
    "softplus": nn.Softplus,
    "exp": None,  # built by _make_activation
}


class _Exp(nn.Module):
    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return torch.exp(x)


def _make_activation(name: str, where: str) -> nn.Module:
    if name not in ACTIVATIONS:
        raise InputError(f"{where}: unknown activation {name!r} (known: {', '.join(ACTIVATIONS)})")
    if name == "exp":
        return _Exp()
    if name in ("relu", "leaky_relu", "silu"):  # safe in place after a linear layer
        return ACTIVATIONS[name](inplace=True)
    return ACTIVATIONS[name]()


def log_median(target: torch.Tensor) -> torch.Tensor:
    """log of the per-channel median (C,) of target values (N, C), clamped to >= 1e-4 first: where an
    exp-output decoder starts so that its first predictions sit at the data's scale."""
    return target.median(0).values.clamp(min=1e-4).log()


class MLP(nn.Module):
    """in_dim -> [hidden] * n_hidden_layers -> out_dim, `activation` after each hidden layer and
    `out_activation` (None for linear) after the last. forward: (..., in_dim) -> (..., out_dim)."""

    def __init__(self, in_dim: int, hidden: int, n_hidden_layers: int, out_dim: int,
                 activation: str = "relu", out_activation: str | None = None) -> None:
        super().__init__()
        for name, v, lo in (("in_dim", in_dim, 1), ("hidden", hidden, 1), ("n_hidden_layers", n_hidden_layers, 0),
                            ("out_dim", out_dim, 1)):
            check_int(v, f"MLP.{name}", lo)
        dims = [in_dim] + [hidden] * n_hidden_layers + [out_dim]
        layers: list[nn.Module] = []
        for i, (a, b) in enumerate(zip(dims[:-1], dims[1:])):
            layers.append(nn.Linear(a, b))
            if i < len(dims) - 2:
                layers.append(_make_activation(activation, "MLP.activation"))
        if out_activation is not None:
            layers.append(_make_activation(out_activation, "MLP.out_activation"))
        self.net = nn.Sequential(*layers)
        self.dims = tuple(dims)
        self.has_out_activation = out_activation is not None

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if x.shape[-1] != self.dims[0]:
            raise InputError(f"MLP input: expected last dimension {self.dims[0]}, got {tuple(x.shape)}")
        return self.run_layers(x)

    def run_layers(self, x: torch.Tensor, start: int = 0) -> torch.Tensor:
        """x through the layers of `net` from index `start` on, unchecked, each by its own forward: a module call
        per layer costs as much as a small layer (runtimes that compute the first layer themselves start at 1)."""
        for layer in itertools.islice(self.net, start, None):
            x = layer.forward(x)
        return x

    @torch.no_grad()
    def start_constant(self, value: torch.Tensor) -> None:
        """Make the network output the constant `value` (out_dim,) before its out_activation: last layer
        weights 0, biases `value` (gradients still reach every layer after the first step)."""
        last = self.linears()[-1]
        if value.shape != last.bias.shape:
            raise InputError(f"MLP.start_constant: expected a value of shape {tuple(last.bias.shape)}, "
                             f"got {tuple(value.shape)}")
        last.weight.zero_()
        last.bias.copy_(value.to(last.bias))

    def linears(self) -> list[nn.Linear]:
        """The linear layers, input to output."""
        return [m for m in self.net if isinstance(m, nn.Linear)]

    def flops(self) -> int:
        """Floating-point operations per evaluation: 2 in out per linear layer (per output, `in` multiplies
        and `in` adds: in - 1 partial sums plus the bias), plus one per activated output."""
        lin = sum(2 * a * b for a, b in zip(self.dims[:-1], self.dims[1:]))
        act = sum(self.dims[1:-1]) + (self.dims[-1] if self.has_out_activation else 0)
        return lin + act

    def num_parameters(self) -> int:
        """Weights and biases."""
        return sum(p.numel() for p in self.parameters())
