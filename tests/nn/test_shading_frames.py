import torch

from neumat.core.frames import frame_from_normal_tangent, to_local
from neumat.nn.shading_frames import ShadingFrame, lift_to_hemisphere
from neumat.warp.hemisphere import sample_cosine_hemisphere


def _dirs(n, seed=0):
    g = torch.Generator().manual_seed(seed)
    return (sample_cosine_hemisphere(torch.rand(n, 2, generator=g)),
            sample_cosine_hemisphere(torch.rand(n, 2, generator=g)))


def test_identity_at_initialisation():
    wi, wo = _dirs(100)
    frame = ShadingFrame(5)
    a, b = frame(torch.randn(100, 5), wi, wo)
    torch.testing.assert_close(a, wi)
    torch.testing.assert_close(b, wo)


def test_decoded_frame_matches_core_frames_and_lifts_below_horizon():
    wi, wo = _dirs(500, seed=1)
    frame = ShadingFrame(3, weight_scale=0.5)
    with torch.no_grad():
        frame.decode.weight.normal_()
    z = torch.randn(500, 3)
    v = (frame.decode.bias + frame.weight_scale * z @ frame.decode.weight.t()).detach()
    n = v[:, :3] / v[:, :3].norm(dim=-1, keepdim=True)
    t, b = frame_from_normal_tangent(n, v[:, 3:])
    ref = to_local(wi, t, b, n)
    got, _ = frame(z, wi, wo)
    torch.testing.assert_close(got[:, :2], ref[:, :2], atol=1e-5, rtol=0)
    torch.testing.assert_close(got[:, 2], ref[:, 2].abs(), atol=2e-3, rtol=0)
    assert bool((ref[:, 2] < 0).any())
    torch.testing.assert_close(got.norm(dim=-1), torch.ones(500), atol=1e-5, rtol=0)


def test_lift_has_finite_gradient_on_the_rim():
    w = torch.tensor([[1.0, 0.0, 0.0], [0.6, 0.8, 0.0]], requires_grad=True)
    lift_to_hemisphere(w).sum().backward()
    assert bool(torch.isfinite(w.grad).all())


def test_several_frames_are_independent_single_frames():
    """frames = 2 (Zeltner et al.'s Eq. 7): each 3-block of the output equals a one-frame decoder with that
    frame's rows of the decoding layer; at initialisation both are the geometric frame (float64: the lift
    sqrt(1 - x^2 - y^2) amplifies float32 rounding near the rim)."""
    g = torch.Generator().manual_seed(5)
    wi, wo = (torch.nn.functional.normalize(w.double(), dim=-1) for w in _dirs(200, seed=2))
    z = torch.randn(200, 4, generator=g, dtype=torch.float64)
    two = ShadingFrame(4, weight_scale=0.3, frames=2).double()
    a, b = two(z, wi, wo)
    torch.testing.assert_close(a, torch.cat([wi, wi], -1))
    torch.testing.assert_close(b, torch.cat([wo, wo], -1))
    with torch.no_grad():
        two.decode.weight.copy_(torch.randn(12, 4, generator=g, dtype=torch.float64))
        two.decode.bias.copy_(torch.randn(12, generator=g, dtype=torch.float64))
    a, b = two(z, wi, wo)
    for k in range(2):
        one = ShadingFrame(4, weight_scale=0.3).double()
        with torch.no_grad():
            one.decode.weight.copy_(two.decode.weight[6 * k:6 * k + 6])
            one.decode.bias.copy_(two.decode.bias[6 * k:6 * k + 6])
        ai, bi = one(z, wi, wo)
        torch.testing.assert_close(a[:, 3 * k:3 * k + 3], ai)
        torch.testing.assert_close(b[:, 3 * k:3 * k + 3], bi)
    assert two.flops() == 2 * ShadingFrame(4, frames=1).flops()
