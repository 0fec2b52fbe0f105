import math

import pytest
import torch

from neumat.core.errors import InputError
from neumat.core.query import Query
from neumat.models.registry import build_model, model_class
from neumat.warp.hemisphere import sample_cosine_hemisphere


def _queries(n, seed=0, dtype=torch.float64):
    g = torch.Generator().manual_seed(seed)
    wi = sample_cosine_hemisphere(torch.rand(n, 2, generator=g, dtype=dtype))
    wo = sample_cosine_hemisphere(torch.rand(n, 2, generator=g, dtype=dtype))
    return Query(wi, wo, uv=torch.rand(n, 2, generator=g, dtype=dtype))


def _set_uniform(m, albedo, f0, slopes, alpha_x, alpha_y, phi):
    raw = [math.log(math.expm1(albedo))] * 3 + [math.log(math.expm1(f0))] * 3 + list(slopes) + \
          [math.log(alpha_x), math.log(alpha_y), math.cos(2 * phi), math.sin(2 * phi)]
    with torch.no_grad():
        for p in m.spatial.raw:
            p.copy_(torch.tensor(raw, dtype=p.dtype).view(-1, 1, 1).expand_as(p))


def _reference(wi, wo, albedo, f0, ax, ay):
    """Closed-form Lambert + anisotropic GGX with Schlick Fresnel in the geometric frame (float64)."""
    h = (wi + wo) / (wi + wo).norm(dim=-1, keepdim=True)
    d = 1 / (math.pi * ax * ay * ((h[:, 0] / ax) ** 2 + (h[:, 1] / ay) ** 2 + h[:, 2] ** 2) ** 2)

    def g1(w):
        return 2 * w[:, 2] / (w[:, 2] + torch.sqrt(w[:, 2] ** 2 + (ax * w[:, 0]) ** 2 + (ay * w[:, 1]) ** 2))

    f = f0 + (1 - f0) * (1 - (wi * h).sum(-1)) ** 5
    return (albedo / math.pi + d * g1(wi) * g1(wo) * f / (4 * wi[:, 2] * wo[:, 2])).unsqueeze(-1).expand(-1, 3)


def test_flat_texel_is_lambert_plus_anisotropic_ggx():
    m = build_model({"type": "ggx-mipmap", "spatial_size": 8}).double()
    _set_uniform(m, 0.4, 0.05, (0.0, 0.0), 0.2, 0.5, 0.0)
    q = _queries(2000)
    torch.testing.assert_close(m.eval(q), _reference(q.wi, q.wo, 0.4, 0.05, 0.2, 0.5), rtol=1e-6, atol=1e-9)
    _set_uniform(m, 0.4, 0.05, (0.0, 0.0), 0.2, 0.5, math.pi / 2)  # rotated ellipse = swapped alphas
    torch.testing.assert_close(m.eval(q), _reference(q.wi, q.wo, 0.4, 0.05, 0.5, 0.2), rtol=1e-6, atol=1e-9)


def test_tilted_normal_uses_the_cosine_ratio_and_reciprocity():
    m = build_model({"type": "ggx-mipmap", "spatial_size": 8}).double()
    _set_uniform(m, 0.3, 0.04, (0.4, -0.2), 0.3, 0.3, 0.0)
    q = _queries(1000, seed=1)
    f = m.eval(q)
    torch.testing.assert_close(m.eval(q.swapped()), f)
    n = torch.tensor([0.4, -0.2, 1.0], dtype=torch.float64)
    n = n / n.norm()
    below = (q.wi @ n <= 0) | (q.wo @ n <= 0)
    assert bool(below.any()) and bool((f[below] == 0).all())
    # isotropic: value = (Lambert + GGX about n) * symmetrised cosine ratio
    li, lo = q.wi @ n, q.wo @ n
    h = (q.wi + q.wo) / (q.wi + q.wo).norm(dim=-1, keepdim=True)
    a2, nh = 0.09, h @ n
    d = a2 / (math.pi * (nh ** 2 * (a2 - 1) + 1) ** 2)
    g1 = lambda c: 2 * c / (c + torch.sqrt(a2 + (1 - a2) * c ** 2))  # noqa: E731
    fr = 0.04 + 0.96 * (1 - (q.wi * h).sum(-1)) ** 5
    ref = (0.3 / math.pi + d * g1(li) * g1(lo) * fr / (4 * li * lo)) * 0.5 * (li / q.wi[:, 2] + lo / q.wo[:, 2])
    ok = ~below
    torch.testing.assert_close(f[ok, 0], ref[ok], rtol=1e-6, atol=1e-9)


def test_roundtrip_gradients_and_bad_config():
    m = build_model({"type": "ggx-mipmap", "spatial_size": 16})
    clone = model_class("ggx-mipmap")(config=m.cfg)
    clone.load_state_dict(m.state_dict())
    q = _queries(64, dtype=torch.float32)
    q = Query(q.wi, q.wo, uv=q.uv, footprint=(torch.eye(2) * 0.05 ** 2).expand(64, 2, 2).contiguous())
    f = m.eval(q)
    torch.testing.assert_close(clone.eval(q), f)
    f.sum().backward()
    assert all(torch.isfinite(p.grad).all() for p in m.parameters() if p.grad is not None)
    assert m.size_bytes("fp32") == 12 * 4 * sum((16 >> l) ** 2 for l in range(5))
    with pytest.raises(InputError, match="init_alpha"):
        build_model({"type": "ggx-mipmap", "init_alpha": 0.0})
