"""Targets for a model that is constant on HEALPix pixel pairs: the reference averaged over the pair.

NeuBRDF's runtime form (1/4 corner weights) reads one feature per pixel of wi and one per pixel of the mirrored
wo, so whatever its MLP it is constant on every (pixel of wi, pixel of wo) pair. The best such function in L2 is
the reference averaged over the pair; a loss on per-query values instead (a log loss especially) pulls a
sub-pixel specular peak down to something like its median over the pair, which renders dark. `PixelPairAverage`
estimates the pair average with K points per query (centres of uniformly drawn nested children of the two
pixels), drawn from a given generator (a fit's, so that a resumed fit draws the same points).
"""
from __future__ import annotations

import torch

from neumat.core.errors import InputError
from neumat.core.material import Material, describe_source, upper_hemisphere
from neumat.core.query import Query
from neumat.nn import healpix as hpx

#: sub-pixel levels: a pixel's points are the centres of its 4^LEVELS nested children
LEVELS = 4


class PixelPairAverage(Material):
    """`reference` averaged over the HEALPix pixel pair of (wi, wo) at `nside`, `samples` points per query.

    Each point's wi' and wo' are the centres of uniformly drawn nested children (4^LEVELS per pixel) of the
    pixels of wi and of wo, independently; a child centre below the surface is replaced by the query's own
    direction (the average covers the pixel's part above the horizon). The pixel of the mirrored wo that
    NeuBRDF reads is the mirror image of wo's own pixel (HEALPix is symmetric about the equator), so the
    average is constant on the runtime form's pairs. eval: (N, 3) in the reference's units, 0 below the
    horizon; estimates are unbiased with a spread falling as 1 / sqrt(samples)."""

    def __init__(self, reference: Material, nside: int, samples: int,
                 generator: torch.Generator | None = None) -> None:
        if not callable(getattr(reference, "eval", None)):
            raise InputError(f"PixelPairAverage: reference must be a Material, got {type(reference).__name__}")
        if isinstance(samples, bool) or not isinstance(samples, int) or samples < 1:
            raise InputError(f"PixelPairAverage samples: expected an integer >= 1, got {samples!r}")
        self.reference, self.nside, self.samples = reference, hpx.check_nside(nside, power_of_two=True), samples
        self.generator = generator if generator is not None else torch.Generator().manual_seed(0)
        self.spatially_varying = getattr(reference, "spatially_varying", False)

    def describe(self) -> str:
        inner = describe_source(self.reference)
        return f"{inner} averaged over N_side {self.nside} pixel pairs ({self.samples} points)"

    def _jitter(self, w: torch.Tensor) -> torch.Tensor:
        """(N, 3) float64 -> (samples, N, 3): child centres inside the pixel of each direction."""
        n, k = self.nside, 4 ** LEVELS
        nest = hpx.ring2nest(n, hpx.vec2pix(n, w))
        pick = torch.randint(k, (self.samples, w.shape[0]), generator=self.generator, device=self.generator.device)
        fine = n * 2 ** LEVELS
        child = hpx.pix2vec(fine, hpx.nest2ring(fine, (nest.unsqueeze(0) * k + pick.to(w.device)).reshape(-1)))
        child = child.to(w.device).view(self.samples, -1, 3)
        return torch.where(child[..., 2:3] > 0, child, w.unsqueeze(0))

    def eval(self, q: Query) -> torch.Tensor:
        """(N, 3) pair averages at q (texture fields, if any, are kept for every point)."""
        if q.wo is None or q.x is not None:
            raise InputError("PixelPairAverage: expected BRDF queries (wi and wo, no surface position x)")
        up = upper_hemisphere(q.wi, q.wo)
        ji, jo = self._jitter(q.wi.double()), self._jitter(q.wo.double())
        extra = {name: getattr(q, name).repeat(self.samples, *[1] * (getattr(q, name).dim() - 1))
                 for name in ("uv", "footprint", "lod") if getattr(q, name) is not None}
        sub = Query(ji.reshape(-1, 3).to(q.dtype), jo.reshape(-1, 3).to(q.dtype), **extra)
        f = self.reference.eval(sub).view(self.samples, -1, 3).mean(0)
        return torch.where(up.unsqueeze(-1), f, 0.0).to(q.dtype)
