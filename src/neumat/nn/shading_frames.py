"""Learned shading frames decoded from a spatial latent (Zeltner et al. 2024; Timonen et al. 2025, Sec. 3.1).

A linear layer maps the latent z (N, D) to a normal and a tangent (3 + 3 values); the normal is
normalised, the tangent made orthogonal to it (Gram-Schmidt) and the bitangent completes a right-handed
frame. Directions are expressed in that frame and then, as Timonen et al. do, projected to the unit disk
and lifted back to the upper hemisphere, w -> (w_x, w_y, sqrt(1 - w_x^2 - w_y^2)): a direction that the
frame puts below the horizon is mirrored above it instead of leaving the domain of the angular textures.
At initialisation (zero weights, bias = (0, 0, 1 | 1, 0, 0)) the frame is the geometric one.

The decoder's weights enter scaled, v = bias + `weight_scale` W z (default 0.1). With Adam, whose steps are
about the learning rate per parameter whatever the gradient's size, this is a learning rate 10x lower for W:
the 6 x D weights act on every texel's frame at once, and at the full rate they tilt the frames of a flat
material by ~20 degrees within a few hundred steps (measured on Wood092 at 64^2, lr 1e-2), a fold that the
decoder then has to undo; the scale keeps them within a few degrees and lowers the fitting error ~9x there.
The function class is unchanged (W can be rescaled at export).
"""
from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from ..core.frames import to_local

_EPS = 1e-12


def lift_to_hemisphere(w: torch.Tensor) -> torch.Tensor:
    """(x, y, sqrt(1 - x^2 - y^2)) of w (N, 3): disk projection and lift; finite gradient at the rim."""
    xy = w[:, :2]
    z = (1 - (xy * xy).sum(-1)).clamp(min=1e-10).sqrt()
    return torch.cat([xy, z.unsqueeze(-1)], -1)


def frame_from_vectors(normal: torch.Tensor, tangent: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Orthonormal (t, b, n), each (N, 3), from unnormalised normal and tangent vectors (N, 3)."""
    n = normal / normal.norm(dim=-1, keepdim=True).clamp(min=_EPS)
    t = tangent - (tangent * n).sum(-1, keepdim=True) * n
    t = t / t.norm(dim=-1, keepdim=True).clamp(min=_EPS)
    return t, torch.cross(n, t, dim=-1), n


class ShadingFrame(nn.Module):
    """forward(z (N, D), wi (N, 3), wo (N, 3)) -> (wi', wo'): directions in the learned frame, lifted.
    weight_scale: factor on the decoder weights (module docstring)."""

    def __init__(self, latent_dim: int, weight_scale: float = 0.1) -> None:
        super().__init__()
        self.weight_scale = float(weight_scale)
        self.decode = nn.Linear(latent_dim, 6)
        with torch.no_grad():
            self.decode.weight.zero_()
            self.decode.bias.copy_(torch.tensor([0.0, 0.0, 1.0, 1.0, 0.0, 0.0]))

    def frame(self, z: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(t, b, n) (N, 3) each."""
        v = F.linear(z, self.decode.weight * self.weight_scale, self.decode.bias)
        return frame_from_vectors(v[:, :3], v[:, 3:])

    def forward(self, z: torch.Tensor, wi: torch.Tensor, wo: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        t, b, n = self.frame(z)
        return lift_to_hemisphere(to_local(wi, t, b, n)), lift_to_hemisphere(to_local(wo, t, b, n))

    def flops(self) -> int:
        """Decode layer, normalisations and Gram-Schmidt (~40), a cross product (9), two 3x3 transforms (30)
        and two lifts (~8)."""
        return 2 * self.decode.in_features * 6 + 40 + 9 + 30 + 8
