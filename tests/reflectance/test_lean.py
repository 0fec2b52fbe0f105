"""LEAN prefiltering of surface parameters for coarse levels (`neumat.reflectance.lean`)."""
import math

import pytest
import torch
import torch.nn.functional as F

from neumat.core.errors import InputError
from neumat.core.query import Query
from neumat.fit.losses import LogCosLoss
from neumat.io.texture_set import TextureSet
from neumat.reflectance.lean import NormalGroup, lean_pyramid
from neumat.reflectance.svbrdf import SVBRDF
from neumat.warp.hemisphere import sample_cosine_hemisphere

PRINCIPLED = NormalGroup(normal=3, roughness=6, alpha_power=2.0)


def _maps(normal: torch.Tensor, roughness: torch.Tensor, color=0.3, metal=1.0) -> torch.Tensor:
    """(8, H, W) SVBRDF parameters: colour, normal, roughness, metalness."""
    h, w = roughness.shape
    n = normal / normal.norm(dim=-1, keepdim=True)
    return torch.cat([torch.full((h, w, 3), color), n, roughness[..., None], torch.full((h, w, 1), metal)],
                     -1).permute(2, 0, 1).contiguous()


def test_flat_constant_maps_are_unchanged_and_level_zero_is_the_input():
    k = _maps(torch.tensor([0.0, 0.0, 1.0]).expand(8, 8, 3), torch.full((8, 8), 0.4))
    levels = lean_pyramid(k, [PRINCIPLED], 4)
    assert levels[0] is k and [tuple(p.shape) for p in levels] == [(8, 8, 8), (8, 4, 4), (8, 2, 2), (8, 1, 1)]
    for p in levels[1:]:
        torch.testing.assert_close(p, k[:, : p.shape[1], : p.shape[2]])


@pytest.mark.parametrize("alpha_power", [2.0, 1.0])
def test_slope_spread_becomes_roughness(alpha_power):
    """A checker of slopes +-s along x over roughness r: one flat normal, alpha'^2 = alpha^2 + s^2."""
    s, r = 0.3, 0.5
    odd = ((torch.arange(8)[:, None] + torch.arange(8)[None, :]) % 2).float()
    n = torch.stack([s * (2 * odd - 1), torch.zeros_like(odd), torch.ones_like(odd)], -1)
    k = _maps(n, torch.full((8, 8), r))
    coarse = lean_pyramid(k, [NormalGroup(3, 6, alpha_power)], 2)[1]
    torch.testing.assert_close(coarse[3:6], torch.tensor([0.0, 0.0, 1.0]).view(3, 1, 1).expand(3, 4, 4))
    alpha = math.sqrt(r ** (2 * alpha_power) + s * s)
    torch.testing.assert_close(coarse[6], torch.full((4, 4), alpha ** (1 / alpha_power)))
    torch.testing.assert_close(coarse[[0, 1, 2, 7]], k[[0, 1, 2, 7], :4, :4])


def test_random_maps_match_a_per_block_reference():
    g = torch.Generator().manual_seed(0)
    n = torch.randn(16, 16, 3, generator=g, dtype=torch.float64) * torch.tensor([0.4, 0.4, 0.1], dtype=torch.float64)
    n[..., 2] += 1
    k = _maps(n, torch.rand(16, 16, generator=g, dtype=torch.float64)).double()
    coarse = lean_pyramid(k, [PRINCIPLED], 3)[2]
    for i, j in [(0, 0), (1, 3), (3, 2)]:
        block = k[:, 4 * i: 4 * i + 4, 4 * j: 4 * j + 4].reshape(8, -1)
        b = block[3:5] / block[5]
        mean = b.mean(1)
        alpha2 = (block[6] ** 4).mean() + (b * b).sum(0).mean() - (mean * mean).sum()
        normal = torch.cat([mean, torch.ones(1, dtype=torch.float64)])
        torch.testing.assert_close(coarse[3:6, i, j], normal / normal.norm())
        torch.testing.assert_close(coarse[6, i, j], alpha2.clamp(max=1) ** 0.25)
        torch.testing.assert_close(coarse[[0, 1, 2, 7], i, j], block[[0, 1, 2, 7]].mean(1))


def test_lean_beats_box_filtering_on_glossy_ripples():
    """Normal-mapped glossy metal seen from afar: box-averaged normals keep the lobe sharp, LEAN widens it as the
    filtered reference does. Measured relative L1 at levels 2 and 3: 1.69 / 1.88 (box), 0.91 / 0.94 (LEAN)."""
    size = 32
    x = (torch.arange(size) + 0.5) / size
    yy, xx = torch.meshgrid(x, x, indexing="ij")
    n = torch.stack([0.4 * torch.sin(16 * math.pi * xx), 0.4 * torch.cos(8 * math.pi * yy), torch.ones_like(xx)], -1)
    k = _maps(n, torch.full((size, size), 0.2))
    reference = SVBRDF(_texture_set(k), samples=256)
    lean = lean_pyramid(k, list(reference.surface_normal_groups), 4)
    g = torch.Generator().manual_seed(1)
    for level in (2, 3):
        cells = size >> level
        u = torch.rand(4096, 4, generator=g)
        uv = (torch.randint(0, cells, (4096, 2), generator=g) + 0.5) / cells     # coarse texel centres
        q = Query(sample_cosine_hemisphere(u[:, :2]), sample_cosine_hemisphere(u[:, 2:4]), uv=uv,
                  lod=torch.full((4096,), float(level)))
        target = reference.eval(q)
        point = Query(q.wi, q.wo, uv=uv)
        err = {}
        for name, maps in (("box", F.avg_pool2d(k[None], 1 << level)[0]), ("lean", lean[level])):
            f = SVBRDF(_texture_set(maps)).eval(point)
            err[name] = float((f - target).abs().sum() / target.abs().sum())
        assert err["lean"] < 0.7 * err["box"], err
        assert LogCosLoss()(SVBRDF(_texture_set(lean[level])).eval(point), target, q) < 0.08


def _texture_set(k: torch.Tensor) -> TextureSet:
    m = k.permute(1, 2, 0)
    n = m[..., 3:6] / m[..., 3:6].norm(dim=-1, keepdim=True)
    return TextureSet(color=m[..., :3].contiguous(), normal=n.contiguous(), roughness=m[..., 6].contiguous(),
                      metalness=m[..., 7].contiguous(), height=torch.zeros(m.shape[:2]), name="prefiltered")


def test_bad_input_raises():
    k = _maps(torch.tensor([0.0, 0.0, 1.0]).expand(4, 4, 3), torch.full((4, 4), 0.4))
    with pytest.raises(InputError, match="does not fit 8"):
        lean_pyramid(k, [NormalGroup(normal=6, roughness=2)], 2)
    with pytest.raises(InputError, match="does not fit 8"):
        lean_pyramid(k, [NormalGroup(normal=3, roughness=4)], 2)
    with pytest.raises(InputError, match="levels"):
        lean_pyramid(k, [PRINCIPLED], 4)
    with pytest.raises(InputError, match="(K, H, W)"):
        lean_pyramid(k[0], [PRINCIPLED], 1)
