"""Learned shading frames decoded from a spatial latent (Zeltner et al. 2024; Timonen et al. 2025, Sec. 3.1).

A linear layer maps the latent z (N, D) to a normal and a tangent (3 + 3 values) per frame (Zeltner et al.
decode N = 2 frames with one layer of 12 outputs, their Eq. 7; Timonen et al. one); each normal is
normalised, the tangent made orthogonal to it (Gram-Schmidt) and the bitangent completes a right-handed
frame. Directions are expressed in that frame and then, as Timonen et al. do, projected to the unit disk
and lifted back to the upper hemisphere, w -> (w_x, w_y, sqrt(1 - w_x^2 - w_y^2)): a direction that the
frame puts below the horizon is mirrored above it instead of leaving the domain of the angular textures.
At initialisation (zero weights, bias = (0, 0, 1 | 1, 0, 0) per frame) every frame is the geometric one.

Details: src/neumat/methods/latent_mlp/NOTES.md, section `neumat.nn.shading_frames`.
"""
from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from ..core.checks import check_int
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
    """forward(z (N, D), wi (N, 3), wo (N, 3)) -> (wi', wo'), each (N, 3 frames): directions in every learned
    frame, lifted, frame after frame. weight_scale: factor on the decoder weights
    (src/neumat/methods/latent_mlp/NOTES.md)."""

    def __init__(self, latent_dim: int, weight_scale: float = 0.1, frames: int = 1) -> None:
        super().__init__()
        check_int(frames, "ShadingFrame.frames")
        self.weight_scale, self.frames = float(weight_scale), frames
        self.decode = nn.Linear(latent_dim, 6 * frames)
        with torch.no_grad():
            self.decode.weight.zero_()
            self.decode.bias.copy_(torch.tensor([0.0, 0.0, 1.0, 1.0, 0.0, 0.0]).repeat(frames))

    def frame(self, z: torch.Tensor, index: int = 0) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(t, b, n) (N, 3) each of frame `index`."""
        return self._frames(z)[index]

    def _frames(self, z: torch.Tensor) -> list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]]:
        v = F.linear(z, self.decode.weight * self.weight_scale, self.decode.bias)
        return [frame_from_vectors(v[:, 6 * k:6 * k + 3], v[:, 6 * k + 3:6 * k + 6]) for k in range(self.frames)]

    def forward(self, z: torch.Tensor, wi: torch.Tensor, wo: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        out_i, out_o = [], []
        for t, b, n in self._frames(z):
            out_i.append(lift_to_hemisphere(to_local(wi, t, b, n)))
            out_o.append(lift_to_hemisphere(to_local(wo, t, b, n)))
        return torch.cat(out_i, -1), torch.cat(out_o, -1)

    def flops(self) -> int:
        """Decode layer; per frame normalisations and Gram-Schmidt (~40), a cross product (9), two 3x3
        transforms (30) and two lifts (~8)."""
        return 2 * self.decode.in_features * 6 * self.frames + (40 + 9 + 30 + 8) * self.frames
