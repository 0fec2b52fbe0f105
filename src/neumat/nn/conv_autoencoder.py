"""A 3D convolutional autoencoder with a bottleneck, for clustering tabulated reflectance volumes
(NeuBRDF Sec. 3.3: the bottleneck codes of similar materials lie close, and k-means groups them).

Input: volumes (M, C, R, R, R) (e.g. log reflectance on a Rusinkiewicz grid, C = 3 colour channels),
R a power of two >= 4. Encoder: stride-2 3x3x3 convolutions halving R down to 2, then a linear map to the
code; decoder: the mirror image with transposed convolutions.
"""
from __future__ import annotations

import torch
from torch import nn

from neumat.core.checks import check_finite, check_int
from neumat.core.errors import InputError


class ConvAutoencoder(nn.Module):
    """encode: (M, C, R, R, R) -> (M, code_dim); decode: (M, code_dim) -> (M, C, R, R, R)."""

    def __init__(self, channels: int = 3, resolution: int = 16, code_dim: int = 8, width: int = 16) -> None:
        super().__init__()
        for name, v, lo in (("channels", channels, 1), ("resolution", resolution, 4), ("code_dim", code_dim, 1),
                            ("width", width, 1)):
            check_int(v, f"ConvAutoencoder.{name}", lo)
        if resolution & (resolution - 1):
            raise InputError(f"ConvAutoencoder.resolution: expected a power of two, got {resolution}")
        self.channels, self.resolution = channels, resolution
        levels = resolution.bit_length() - 2  # halvings from R down to 2
        enc: list[nn.Module] = []
        c = channels
        for _ in range(levels):
            enc += [nn.Conv3d(c, width, 3, stride=2, padding=1), nn.ReLU()]
            c = width
        self.encoder = nn.Sequential(*enc, nn.Flatten(), nn.Linear(width * 8, code_dim))
        dec: list[nn.Module] = [nn.Linear(code_dim, width * 8), nn.Unflatten(1, (width, 2, 2, 2))]
        for i in range(levels):
            last = i == levels - 1
            dec.append(nn.ConvTranspose3d(width, channels if last else width, 4, stride=2, padding=1))
            if not last:
                dec.append(nn.ReLU())
        self.decoder = nn.Sequential(*dec)

    def _check(self, x: torch.Tensor) -> None:
        r, c = self.resolution, self.channels
        if not isinstance(x, torch.Tensor) or x.dim() != 5 or tuple(x.shape[1:]) != (c, r, r, r):
            shape = tuple(x.shape) if isinstance(x, torch.Tensor) else type(x).__name__
            raise InputError(f"ConvAutoencoder input: expected shape (M, {c}, {r}, {r}, {r}), got {shape}")
        check_finite(x, "ConvAutoencoder input")

    def encode(self, x: torch.Tensor) -> torch.Tensor:
        self._check(x)
        return self.encoder(x)

    def decode(self, code: torch.Tensor) -> torch.Tensor:
        return self.decoder(code)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.decode(self.encode(x))


def train_autoencoder(model: ConvAutoencoder, volumes: torch.Tensor, steps: int = 500, lr: float = 3e-3,
                      seed: int = 0) -> list[float]:
    """Fit `model` to reconstruct `volumes` (M, C, R, R, R) (full batch, Adam, MSE). Returns the loss per
    step. The model's initial weights are re-seeded with `seed` for reproducibility."""
    check_int(steps, "steps")
    model._check(volumes)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        for m in model.modules():
            if isinstance(m, (nn.Linear, nn.Conv3d, nn.ConvTranspose3d)):
                m.reset_parameters()
    opt = torch.optim.Adam(model.parameters(), lr=lr)
    losses = []
    model.train()
    for _ in range(steps):
        opt.zero_grad()
        loss = (model(volumes) - volumes).square().mean()
        loss.backward()
        opt.step()
        losses.append(loss.item())
    model.eval()
    return losses
