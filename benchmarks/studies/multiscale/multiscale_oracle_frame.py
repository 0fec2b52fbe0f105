"""Diagnostic for `benchmarks/studies/multiscale/multiscale.py`: is the learned shading frame what holds the gated model back at
the finest scales? Adds a model `multiscale-oracle-frame`, the gated model whose frame is not learned but
taken from the reference's own normal map (bilinear at the footprint centre, unfiltered: exact at the finest
scales, where the apparent BRDF is the normal-mapped lobe), and runs the benchmark with all its options.

    OMP_NUM_THREADS=1 python benchmarks/studies/multiscale/multiscale_oracle_frame.py --materials ../shared/data/svbrdf/Wood092_1K \
        --models multiscale-oracle-frame --steps 6000 --batch 2048 --samples 8 --ref-samples 64 --max-size 64 \
        --resolution 32 --scales 7 --hdr-queries 16384 --short-run-optimiser
"""
from __future__ import annotations

import torch
from torch import nn

import multiscale as benchmark
from neumat.core.frames import to_local
from neumat.methods.latent_mlp.multiscale import MultiScale
from neumat.models.registry import MODELS
from neumat.nn.shading_frames import lift_to_hemisphere
from neumat.reflectance.svbrdf import SVBRDF

_SOURCES: list[SVBRDF] = []


class _RecordedSVBRDF(SVBRDF):
    """The benchmark's SVBRDF, remembered so that the oracle frame can read the texture set being fitted."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        _SOURCES.append(self)


class NormalMapFrame(nn.Module):
    """forward(z, wi, wo) -> wi, wo in the normal-map frame at `self.uv` (N, 2) of the latest source, lifted."""

    uv: torch.Tensor

    def forward(self, z: torch.Tensor, wi: torch.Tensor, wo: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        source = _SOURCES[-1]
        t, b, n = source._shading_frame(source.parameters_at(self.uv)["normal"])
        return lift_to_hemisphere(to_local(wi, t, b, n)), lift_to_hemisphere(to_local(wo, t, b, n))

    def flops(self) -> int:
        """Two 3 x 3 transforms and two lifts (the normal-map fetch is a texture read)."""
        return 30 + 8


@MODELS.register("multiscale-oracle-frame")
class OracleFrameMultiScale(MultiScale):
    """The gated model with `NormalMapFrame` in place of the learned frame (same recipe: name "multiscale")."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.frame = NormalMapFrame()

    def latents(self, q):
        self.frame.uv = q.uv
        return super().latents(q)


if __name__ == "__main__":
    benchmark.SVBRDF = _RecordedSVBRDF
    benchmark.main()
