"""Online training data for translucent-object models: every batch traced fresh by Mitsuba (NeuPreSS, Sec. 4.2,
trains Mitsuba-in-the-loop), so no sample is reused and the L2 fit converges to S_hat's mean, not to one noisy
draw of it.

A batch is drawn as `collect_observations` draws a file's views (a random light and a random jittered orthographic
view per image, the rays that hit the object), and is a function of (seed, step) alone: a resumed fit re-traces the
same batches.
"""
from __future__ import annotations

import math

import torch

from ..core.checks import check_int
from ..core.errors import InputError
from ..reflectance.translucent import TranslucentObject, call_seed
from ..warp.sphere import sample_uniform_sphere
from .translucent_observations import Observations, orbit_rays

#: views drawn for one batch before a draw that never hits the object gives up
MAX_EMPTY_VIEWS = 64
#: most views whose first hits one Mitsuba call finds
MAX_BLOCK = 64
#: share of a view's rays assumed to hit before any did (a sphere fills ~0.26 of its orbit view)
EXPECTED_HIT_FRACTION = 0.25


class OnlineObservations:
    """Fresh path-traced observations of `obj` on demand: `draw(step, n)` gives n of them from newly drawn views
    of `resolution`^2 jittered rays each (one light direction and one Mitsuba trace per view, so fewer, larger
    views cost fewer calls), `spp` paths per observation, reproducible from (seed, step)."""

    def __init__(self, obj: TranslucentObject, resolution: int = 32, spp: int = 16, seed: int = 0) -> None:
        check_int(resolution, "online resolution")
        check_int(spp, "online spp")
        check_int(seed, "online seed", 0)
        self.obj, self.resolution, self.spp, self.seed = obj, resolution, spp, seed

    @classmethod
    def from_observations(cls, observations: Observations, resolution: int = 32, spp: int = 16, seed: int = 0,
                          who: str = "online source") -> "OnlineObservations":
        """The online source of the object an observations file describes (`Observations.object_config`, written
        by `neumat translucent trace`); InputError naming `who` when it has no description."""
        from ..core.config import config_from_dict
        from ..reflectance.translucent import TranslucentConfig

        if observations.object_config is None:
            raise InputError(f"{who}: tracing online needs the object the observations were traced from, but they "
                             "carry no object description (write them with `neumat translucent trace`)")
        config = config_from_dict(TranslucentConfig, observations.object_config)
        return cls(TranslucentObject(config, spp=spp, seed=seed), resolution=resolution, spp=spp, seed=seed)

    def describe(self) -> str:
        return f"online {self.obj.describe()}, {self.resolution}^2-ray views"

    def draw(self, step: int, n: int) -> Observations:
        """Exactly n observations (CPU float32) from fresh views: views are drawn (and intersected in blocks, one
        Mitsuba call each) until n rays have hit the object, the last view's hits subsampled at random; the same
        (seed, step) gives the same observations."""
        check_int(step, "online draw step", 0)
        check_int(n, "online draw n")
        obj, pixels = self.obj, self.resolution ** 2
        gen = torch.Generator().manual_seed(call_seed(self.seed, step))
        views: list[tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]] = []
        total, drawn, hits = 0, 0, 0
        while total < n:
            if drawn >= MAX_EMPTY_VIEWS and hits == 0:
                raise InputError(f"online draw: {drawn} views of {obj.describe()} in a row missed it")
            fraction = hits / (drawn * pixels) if hits else EXPECTED_HIT_FRACTION
            block = min(MAX_BLOCK, max(1, math.ceil((n - total) / max(fraction * pixels, 1.0))))
            rays = []
            for _ in range(block):
                light, view = sample_uniform_sphere(torch.rand(2, 2, generator=gen, dtype=torch.float64))
                rays.append((light, *orbit_rays(obj, view, self.resolution, gen)))
            o_all, d_all = torch.cat([r[1] for r in rays]), torch.cat([r[2] for r in rays])
            hit, x_all, n_all = obj.first_hits(o_all, d_all)  # one call for the block
            counts = hit.reshape(block, pixels).sum(1).tolist()
            drawn, hits = drawn + block, hits + sum(counts)
            offsets = [0]
            for c in counts:
                offsets.append(offsets[-1] + c)
            for k, (light, o, d) in enumerate(rays):
                m = counts[k]
                if m == 0 or total >= n:
                    continue
                mask = hit[k * pixels:(k + 1) * pixels]
                keep = torch.arange(m)
                if m > n - total:
                    keep = torch.randperm(m, generator=gen)[:n - total].sort().values
                x, normal = x_all[offsets[k]:offsets[k + 1]], n_all[offsets[k]:offsets[k + 1]]
                views.append((light, o[mask][keep], d[mask][keep], x[keep], normal[keep]))
                total += keep.numel()
        parts: dict[str, list[torch.Tensor]] = {"x": [], "n": [], "wo": [], "wi": [], "value": []}
        for k, (light, o, d, x, normal) in enumerate(views):
            value = obj.trace(o, d, light, spp=self.spp, seed=call_seed(self.seed, step, k))
            for name, t in (("x", x), ("n", normal), ("wo", -d), ("wi", light.expand(len(o), 3)), ("value", value)):
                parts[name].append(t.float())
        out = Observations(**{name: torch.cat(ts) for name, ts in parts.items()})
        out.bbox = (torch.from_numpy(obj.bbox_min).float(), torch.from_numpy(obj.bbox_max).float())
        return out
