"""A ReLU MLP with skip connections between alternate layers (NeuPreSS's appearance network), which can be
switched off for the paper's ablation (Fig. 7)."""
from __future__ import annotations

import torch
from torch import nn

from neumat.core.checks import check_int
from neumat.core.errors import InputError


class SkipMLP(nn.Module):
    """in_dim -> `layers` ReLU layers of `width` -> out_dim (linear output).

    Layer 1 maps the input to `width`; the following layers come in pairs whose input is added to their
    output before the second ReLU (h <- relu(h + W2 relu(W1 h))), the skip connection between alternate
    layers; an odd layer left over is a plain ReLU layer. With `skips=False` the pairs are plain
    (h <- relu(W2 relu(W1 h))): the same layers and parameters without the additions. forward: (..., in_dim) ->
    (..., out_dim).
    """

    def __init__(self, in_dim: int, width: int, layers: int, out_dim: int, skips: bool = True) -> None:
        super().__init__()
        for name, v in (("in_dim", in_dim), ("width", width), ("layers", layers), ("out_dim", out_dim)):
            check_int(v, f"SkipMLP.{name}")
        if not isinstance(skips, bool):
            raise InputError(f"SkipMLP.skips: expected True or False, got {skips!r}")
        self.first = nn.Linear(in_dim, width)
        self.hidden = nn.ModuleList(nn.Linear(width, width) for _ in range(layers - 1))
        self.out = nn.Linear(width, out_dim)
        self.in_dim, self.width, self.layers, self.skips = in_dim, width, layers, skips

    def forward(self, v: torch.Tensor) -> torch.Tensor:
        if v.shape[-1] != self.in_dim:
            raise InputError(f"SkipMLP input: expected last dimension {self.in_dim}, got {tuple(v.shape)}")
        h = torch.relu(self.first(v))
        pairs = len(self.hidden) // 2
        for k in range(pairs):
            t = self.hidden[2 * k + 1](torch.relu(self.hidden[2 * k](h)))
            h = torch.relu(h + t if self.skips else t)
        if len(self.hidden) % 2:
            h = torch.relu(self.hidden[-1](h))
        return self.out(h)

    def num_parameters(self) -> int:
        return sum(p.numel() for p in self.parameters())

    def flops(self) -> int:
        """2 in out per linear layer plus one add per skip connection output (none without skips)."""
        lin = [self.first, *self.hidden, self.out]
        adds = (len(self.hidden) // 2) * self.width if self.skips else 0
        return sum(2 * m.in_features * m.out_features for m in lin) + adds
