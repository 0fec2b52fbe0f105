"""The spatial latent of models built on a learned latent pyramid (`self.spatial`, `cfg.spatial_channels`):
z_s at a query, and the same z_s without gradient as the features a learned importance sampler conditions on
(`neumat.methods.neural_appearance.proxy_sampler`, as Zeltner et al. 2024 feed their sampling decoder the latent
code)."""
from __future__ import annotations

import torch

from neumat.core.query import Query
from neumat.nn.latent_texture import check_footprint


class SpatialLatent:
    """Mixin for spatially varying models with a `LatentPyramid` `self.spatial`."""

    def spatial_latent(self, q: Query, level_u: torch.Tensor | None = None) -> torch.Tensor:
        """z_s (N, D_s) at `latent_uv` of the query and its footprint (or lod); level_u (N,): one level per query
        by Russian roulette instead of the trilinear blend (`neumat.nn.latent_texture.trilinear_flat`)."""
        return self.read_latent(q, level_u)

    def read_latent(self, q: Query, level_u: torch.Tensor | None = None, shifted: bool = True) -> torch.Tensor:
        """z_s (N, D_s) read at `latent_uv(q, footprint)` (shifted) or at q.uv itself; level_u as in
        `spatial_latent`."""
        q.require("uv", who=f"{self.name} (spatially varying)")
        footprint = None if q.footprint is None else check_footprint(q.footprint, "Query.footprint")
        uv = self.latent_uv(q, footprint) if shifted else q.uv
        if level_u is None:
            return self.spatial(uv, footprint, q.lod)
        return self.spatial(uv, footprint, q.lod, level_u)

    def latent_uv(self, q: Query, footprint: torch.Tensor | None) -> torch.Tensor:
        """Where z_s is read (N, 2): q.uv; a model with a parallax offset module moves it."""
        return q.uv

    @property
    def sampling_feature_dim(self) -> int:
        """D_s: the features `sampling_features` gives."""
        return self.cfg.spatial_channels

    def sampling_features(self, q: Query) -> torch.Tensor:
        """z_s (N, D_s) without gradient."""
        with torch.no_grad():
            return self.spatial_latent(q)


def fused_adam(params, lr: float, betas: tuple[float, float], eps: float) -> torch.optim.Adam:
    """torch.optim.Adam on the trainable tensors of `params` (a module's parameters, or a list) with the fused
    kernel (the same update, every texel still stepped each step; one pass per parameter: on one CPU thread the
    Adam step of a 1K pyramid costs about 0.02 s instead of 0.10 s); the default kernel on devices without a
    fused one. The signature of `neumat.fit.phase.Phase.optimizer`."""
    params = [p for p in params if p.requires_grad]
    fused = all(p.device.type in ("cpu", "cuda") and p.is_floating_point() for p in params)
    return torch.optim.Adam(params, lr=lr, betas=betas, eps=eps, fused=fused or None)

