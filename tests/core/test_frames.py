import torch

from neumat.core.frames import frame_from_normal, frame_from_normal_tangent, to_local, to_world


def test_frame_is_orthonormal_right_handed(gen):
    n = torch.nn.functional.normalize(torch.randn(5000, 3, generator=gen, dtype=torch.float64), dim=-1)
    n[0] = torch.tensor([0.0, 0.0, -1.0], dtype=torch.float64)  # the singular case of naive constructions
    n[1] = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    t, b = frame_from_normal(n)
    for u, v in ((t, b), (t, n), (b, n)):
        assert (u * v).sum(-1).abs().max() < 1e-12
    for u in (t, b):
        assert ((u.norm(dim=-1) - 1).abs() < 1e-12).all()
    assert torch.allclose(torch.cross(t, b, dim=-1), n, atol=1e-12)


def test_local_world_round_trip(gen):
    n = torch.nn.functional.normalize(torch.randn(100, 3, generator=gen, dtype=torch.float64), dim=-1)
    t, b = frame_from_normal(n)
    v = torch.randn(100, 3, generator=gen, dtype=torch.float64)
    loc = to_local(v, t, b, n)
    assert torch.allclose(loc[:, 2], (v * n).sum(-1))
    assert torch.allclose(to_world(loc, t, b, n), v, atol=1e-12)


def test_gram_schmidt_tangent(gen):
    n = torch.nn.functional.normalize(torch.randn(100, 3, generator=gen, dtype=torch.float64), dim=-1)
    rough = torch.randn(100, 3, generator=gen, dtype=torch.float64)
    t, b = frame_from_normal_tangent(n, rough)
    assert (t * n).sum(-1).abs().max() < 1e-12
    assert torch.allclose(torch.cross(t, b, dim=-1), n, atol=1e-12)


def test_gram_schmidt_is_layout_independent_and_clamps_degenerate_tangents(gen):
    """Column-major inputs (e.g. transposed texture reads) give the same frame; a tangent parallel to n is
    divided by max(|t|, 1e-12), with finite gradients (as `Tensor.norm` clamped at 1e-12)."""
    n = torch.nn.functional.normalize(torch.randn(300, 3, generator=gen, dtype=torch.float64), dim=-1)
    t = torch.randn(300, 3, generator=gen, dtype=torch.float64)
    column_major = lambda x: x.t().contiguous().t()  # noqa: E731
    for a, b in zip(frame_from_normal_tangent(n, t), frame_from_normal_tangent(column_major(n), column_major(t))):
        torch.testing.assert_close(a, b, rtol=0, atol=1e-15)
    t = (n[:2] * 3).requires_grad_()
    tangent, _ = frame_from_normal_tangent(n[:2], t)
    residual = t - (t * n[:2]).sum(-1, keepdim=True) * n[:2]
    reference = residual / residual.norm(dim=-1, keepdim=True).clamp(min=1e-12)
    torch.testing.assert_close(tangent, reference)
    (grad,) = torch.autograd.grad(tangent.sum(), t)
    (ref_grad,) = torch.autograd.grad(reference.sum(), t)
    assert bool(torch.isfinite(grad).all())
    torch.testing.assert_close(grad, ref_grad)
