"""Reflectance errors: exact agreement with a numpy computation on recorded queries, and the default query
distribution checked against closed-form expectations."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from neumat import Material, Query
from neumat.core.errors import InputError
from neumat.metrics.hdr import cosine_queries, reflectance_errors


class Constant(Material):
    """f = value everywhere (test only)."""

    def __init__(self, value):
        self.value = torch.tensor(value, dtype=torch.float32)
        self.name = f"constant{tuple(value)}"

    def eval(self, q):
        return self.value.to(q.wi).expand(len(q), 3)


class CosineLobe(Material):
    """f = scale * wo_z (+ offset * wi_z) (test only)."""

    def __init__(self, scale=(1.0, 1.0, 1.0), offset=0.0):
        self.scale = torch.tensor(scale)
        self.offset = offset

    def eval(self, q):
        return (q.wo[:, 2:3] + self.offset * q.wi[:, 2:3]) * self.scale.to(q.wi)


class Texture(Material):
    """f = (u, v, u v), spatially varying (test only)."""

    spatially_varying = True

    def eval(self, q):
        q.require("uv")
        u, v = q.uv[:, 0], q.uv[:, 1]
        return torch.stack([u, v, u * v], -1)


def numpy_errors(f: np.ndarray, g: np.ndarray, cos_i: np.ndarray) -> dict[str, float]:
    """The documented formulas in float64 numpy (f: reference, g: model, (N, 3))."""
    d = g - f
    cos_i = np.maximum(cos_i, 0)[:, None]
    return {"rmse_hdr": float(np.sqrt(np.mean(d * d))), "mae_hdr": float(np.mean(np.abs(d))),
            "rel_err": float(np.abs(d).sum() / np.abs(f).sum()),
            "log_err": float(np.mean(np.abs(np.log(1 + np.maximum(f * cos_i, 0))
                                            - np.log(1 + np.maximum(g * cos_i, 0)))))}


def recording_sampler(store: list):
    """A query_sampler that draws like the default (with uv) and keeps every batch."""
    def draw(n, generator, device):
        q = cosine_queries(n, generator, device, with_uv=True)
        store.append(q)
        return q
    return draw


def test_matches_numpy_on_the_recorded_queries():
    store: list[Query] = []
    model, reference = CosineLobe((0.3, 0.5, 0.9), offset=0.2), Texture()
    got = reflectance_errors(model, reference, n=5000, batch=1024, query_sampler=recording_sampler(store))
    assert [len(q) for q in store] == [1024] * 4 + [904]
    wi = np.concatenate([q.wi.numpy() for q in store]).astype(np.float64)
    wo = np.concatenate([q.wo.numpy() for q in store]).astype(np.float64)
    uv = np.concatenate([q.uv.numpy() for q in store]).astype(np.float64)
    f = np.stack([uv[:, 0], uv[:, 1], uv[:, 0] * uv[:, 1]], -1)
    g = (wo[:, 2:3] + 0.2 * wi[:, 2:3]) * np.array([0.3, 0.5, 0.9])
    want = numpy_errors(f, g, wi[:, 2])
    assert got.keys() == want.keys()
    for key in want:
        assert got[key] == pytest.approx(want[key], rel=1e-6), key


def test_constant_brdfs_against_closed_forms():
    a, b = np.array([0.1, 0.2, 0.3]), np.array([0.2, 0.2, 0.1])
    got = reflectance_errors(Constant(b), Constant(a), n=2 ** 16)
    assert got["rmse_hdr"] == pytest.approx(np.sqrt(np.mean((b - a) ** 2)), rel=1e-6)
    assert got["mae_hdr"] == pytest.approx(np.mean(np.abs(b - a)), rel=1e-6)
    assert got["rel_err"] == pytest.approx(np.abs(b - a).sum() / a.sum(), rel=1e-6)
    # log error: cos_i of a cosine-weighted direction is sqrt(U), U uniform -> 1D integral over U
    nodes, weights = np.polynomial.legendre.leggauss(64)
    c = np.sqrt((nodes + 1) / 2)[:, None]
    h = np.abs(np.log1p(a * c) - np.log1p(b * c)).mean(-1)
    mean = float((weights / 2) @ h)
    sd = math.sqrt(float((weights / 2) @ h ** 2) - mean ** 2)
    assert abs(got["log_err"] - mean) < 4 * sd / math.sqrt(2 ** 16)


def test_default_distribution_cosine_directions_and_uniform_uv():
    n = 2 ** 16
    zero = Constant([0.0, 0.0, 0.0])
    # f = wo_z with wo cosine-weighted: E[cos] = 2/3, E[cos^2] = 1/2
    lobe = reflectance_errors(CosineLobe(), zero, n=n, seed=3)
    assert lobe["mae_hdr"] == pytest.approx(2 / 3, abs=4 * math.sqrt(1 / 2 - 4 / 9) / math.sqrt(n))
    assert lobe["rmse_hdr"] ** 2 == pytest.approx(1 / 2, abs=4 * math.sqrt(1 / 3 - 1 / 4) / math.sqrt(n))
    assert lobe["rel_err"] == math.inf                     # the reference vanishes, the model does not
    # f = (u, v, uv) with uv uniform: channel means 1/2, 1/2, 1/4
    tex = reflectance_errors(Texture(), zero, n=n, seed=3)
    assert tex["mae_hdr"] == pytest.approx((0.5 + 0.5 + 0.25) / 3, abs=4 * 0.3 / math.sqrt(n))


def test_identical_materials_and_determinism():
    m = CosineLobe((1.0, 2.0, 3.0), offset=0.5)
    assert reflectance_errors(m, m, n=1000) == {"rmse_hdr": 0.0, "mae_hdr": 0.0, "rel_err": 0.0, "log_err": 0.0}
    assert reflectance_errors(Constant([0.0] * 3), Constant([0.0] * 3), n=10)["rel_err"] == 0.0
    other = CosineLobe((1.0, 2.0, 3.0))
    first = reflectance_errors(other, m, n=3000, seed=7, batch=512)
    assert reflectance_errors(other, m, n=3000, seed=7, batch=512) == first
    assert reflectance_errors(other, m, n=3000, seed=8, batch=512) != first


def test_runs_without_grad_and_on_the_model_device():
    class Learned(torch.nn.Module, Material):
        def __init__(self):
            super().__init__()
            self.w = torch.nn.Parameter(torch.ones(3))
            self.grad_enabled = []

        def eval(self, q):
            self.grad_enabled.append(torch.is_grad_enabled())
            return self.w * q.wo[:, 2:3]

    model = Learned()
    got = reflectance_errors(model, CosineLobe(), n=4096)
    assert got["rmse_hdr"] < 1e-7 and model.grad_enabled == [False] and model.w.grad is None


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_cuda_gives_the_cpu_numbers():
    model, ref = CosineLobe((0.3, 0.5, 0.9), offset=0.2), Texture()
    cpu = reflectance_errors(model, ref, n=2 ** 16, device="cpu")
    cuda = reflectance_errors(model, ref, n=2 ** 16, device="cuda")
    for key in cpu:
        assert cuda[key] == pytest.approx(cpu[key], rel=1e-5)


def test_bad_arguments_raise():
    ok = Constant([0.1, 0.1, 0.1])
    for kw in ({"n": 0}, {"n": 10.5}, {"batch": 0}):
        with pytest.raises(InputError, match="positive integers"):
            reflectance_errors(ok, ok, **kw)

    class Sphere(Constant):
        full_sphere = True
    with pytest.raises(InputError, match="query_sampler"):
        reflectance_errors(ok, Sphere([0.1] * 3), n=10)

    class Grey(Material):
        def eval(self, q):
            return q.wo[:, 2]
    with pytest.raises(InputError, match=r"model.eval returned \(10,\), expected \(10, 3\)"):
        reflectance_errors(Grey(), ok, n=10)

    def short(n, generator, device):
        return cosine_queries(n - 1, generator, device)
    with pytest.raises(InputError, match="returned 9 queries, expected 10"):
        reflectance_errors(ok, ok, n=10, query_sampler=short)
