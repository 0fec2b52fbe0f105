"""The best any NeuBRDF runtime form could render (issue 32: can chrome reach SSIM 0.99 at N_side 64?).

NeuBRDF's runtime form (1/4 corner weights) reads one feature per HEALPix pixel for wi and one for the mirrored
wo, so whatever its MLP, the shipped model is constant on every pair (pixel of wi, pixel of wo). The best such
function in L2 is the reference averaged over the pixel pair. This script renders that oracle, the average of
the reference over K points per pixel pair (uniform sub-pixel centres of the nested hierarchy, 2^8 per pixel,
drawn independently for wi and wo), under the Table 3 protocol (`neumat.render.comparison`: sphere under the
sky, 128^2, 512 spp, floor = the reference at the next seed), at several N_side. An oracle below the target
means no runtime-form model at that N_side can reach it, however it is trained.

    OMP_NUM_THREADS=1 PYTHONPATH=src python benchmarks/neubrdf_runtime_oracle.py merl_tables/chrome.binary \
        [--nside 64 128 256] [--samples 16] [--resolution 128] [--spp 512]
"""
from __future__ import annotations

import argparse
import time

import torch

from neumat.catalog.open_material import open_material
from neumat.core.material import Material, upper_hemisphere
from neumat.core.query import Query
from neumat.nn import healpix as hpx
from neumat.render.comparison import image_comparison, reference_renders

#: sub-pixel levels: a pixel's points are the centres of its 4^LEVELS nested children
LEVELS = 4


class PixelPairAverage(Material):
    """f averaged over the HEALPix pixel pair of (wi, wo) at `nside`: `samples` points per query, each wi' and
    wo' the centre of a uniformly drawn nested child (4^LEVELS per pixel) of the pixel of wi and of wo. The
    pixel of the mirrored wo that NeuBRDF reads is the mirror image of wo's own pixel (HEALPix is symmetric
    about the equator), so this is constant on the runtime form's pairs. eval: (N, 3), 0 below the horizon."""

    def __init__(self, reference: Material, nside: int, samples: int, seed: int = 0) -> None:
        self.reference, self.nside, self.samples = reference, nside, samples
        self.gen = torch.Generator().manual_seed(seed)

    def _jitter(self, w: torch.Tensor) -> torch.Tensor:
        """(N, 3) -> (samples, N, 3): child centres inside the pixel of each direction."""
        n, k = self.nside, 4 ** LEVELS
        nest = hpx.ring2nest(n, hpx.vec2pix(n, w))
        child = nest.unsqueeze(0) * k + torch.randint(k, (self.samples, w.shape[0]), generator=self.gen)
        fine = n * 2 ** LEVELS
        return hpx.pix2vec(fine, hpx.nest2ring(fine, child.reshape(-1)), w.dtype).view(self.samples, -1, 3)

    def eval(self, q: Query) -> torch.Tensor:
        wi, wo = q.wi.double(), q.wo.double()
        ji, jo = self._jitter(wi), self._jitter(wo)
        sub = Query(ji.reshape(-1, 3).to(q.dtype), jo.reshape(-1, 3).to(q.dtype))
        f = self.reference.eval(sub).view(self.samples, -1, 3).mean(0)
        return torch.where(upper_hemisphere(q.wi, q.wo).unsqueeze(-1), f, 0.0).to(q.dtype)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("source")
    ap.add_argument("--nside", type=int, nargs="+", default=[64, 128, 256])
    ap.add_argument("--samples", type=int, default=16, help="points per pixel pair")
    ap.add_argument("--resolution", type=int, default=128)
    ap.add_argument("--spp", type=int, default=512)
    args = ap.parse_args()
    torch.set_num_threads(1)
    ref = open_material(args.source)
    renders = reference_renders(ref, args.spp, args.resolution)
    print(f"{args.source}: {args.resolution}^2, {args.spp} spp, {args.samples} points per pixel pair")
    print("| N_side | pixel (deg) | image MAE | image RMSE | SSIM | FLIP | floor MAE | floor SSIM | s |")
    print("|---|---|---|---|---|---|---|---|---|")
    for n in args.nside:
        t0 = time.perf_counter()
        m = image_comparison(PixelPairAverage(ref, n, args.samples), ref, args.spp, args.resolution,
                             renders=renders)
        pixel = (4 * torch.pi / hpx.npix(n)) ** 0.5 * 180 / torch.pi
        print(f"| {n} | {pixel:.2f} | {m['mae']:.4f} | {m['rmse']:.4f} | {m['ssim']:.4f} | {m['flip']:.4f} | "
              f"{m['floor_mae']:.5f} | {m['floor_ssim']:.4f} | {time.perf_counter() - t0:.0f} |", flush=True)


if __name__ == "__main__":
    main()
