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
