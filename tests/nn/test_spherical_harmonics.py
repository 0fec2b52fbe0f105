"""Real spherical harmonics: scipy reference, closed forms for l <= 2, orthonormality, projection, input checks."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy import special

from neumat.core.errors import InputError
from neumat.nn.spherical_harmonics import real_sh, sh_count, sh_project


def _dirs(n: int, seed: int = 0, dtype=torch.float64) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return torch.nn.functional.normalize(torch.randn(n, 3, generator=g, dtype=torch.float64), dim=-1).to(dtype)


def _scipy_real_sh(w: np.ndarray, degree: int) -> np.ndarray:
    """Real SH (N, (degree + 1)^2) from scipy's complex Y_l^m, which carry the Condon-Shortley phase (-1)^m.

    Y_l^0 = Y_l^0; m > 0: sqrt(2) (-1)^m Re Y_l^m; m < 0: sqrt(2) (-1)^m Im Y_l^|m|, so that the l = 1 functions
    are +0.488603 (y, z, x).
    """
    theta = np.arccos(np.clip(w[:, 2], -1, 1))
    phi = np.arctan2(w[:, 1], w[:, 0])
    if hasattr(special, "sph_harm_y"):
        def ylm(l, m):  # noqa: E741
            return special.sph_harm_y(l, m, theta, phi)
    else:  # scipy < 1.15
        def ylm(l, m):  # noqa: E741
            return special.sph_harm(m, l, phi, theta)
    out = np.zeros((len(w), (degree + 1) ** 2))
    for l in range(degree + 1):  # noqa: E741
        out[:, l * (l + 1)] = ylm(l, 0).real
        for m in range(1, l + 1):
            y = ylm(l, m)
            out[:, l * (l + 1) + m] = math.sqrt(2) * (-1) ** m * y.real
            out[:, l * (l + 1) - m] = math.sqrt(2) * (-1) ** m * y.imag
    return out


def _quadrature(degree: int):
    """Gauss-Legendre in cos(theta) x trapezoid in phi, exact for products of two SH up to `degree`.

    Returns directions (M, 3) and weights (M,) in steradians (summing to 4 pi).
    """
    n = degree + 2  # exact for polynomials in z of degree 2 n - 1 >= 2 degree
    n_phi = 2 * degree + 2  # exact for trigonometric polynomials of degree < n_phi
    z, wz = np.polynomial.legendre.leggauss(n)
    phi = np.arange(n_phi) * 2 * np.pi / n_phi
    zz, pp = np.meshgrid(z, phi, indexing="ij")
    r = np.sqrt(1 - zz ** 2)
    w = np.stack([r * np.cos(pp), r * np.sin(pp), zz], -1).reshape(-1, 3)
    weights = np.repeat(wz, n_phi) * 2 * np.pi / n_phi
    return torch.from_numpy(w), torch.from_numpy(weights)


@pytest.mark.parametrize("degree", [0, 1, 2, 3, 6])
def test_matches_scipy(degree):
    w = _dirs(3000, seed=degree)
    w[:3] = torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]], dtype=torch.float64)  # poles, equator
    y = real_sh(w, degree)
    assert y.shape == (3000, sh_count(degree)) and y.dtype == torch.float64
    np.testing.assert_allclose(y.numpy(), _scipy_real_sh(w.numpy(), degree), rtol=0, atol=1e-10)


def test_high_degree_is_stable():
    w = _dirs(2000, seed=7)
    w[0] = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    y = real_sh(w, 40)
    assert torch.isfinite(y).all()
    np.testing.assert_allclose(y.numpy(), _scipy_real_sh(w.numpy(), 40), rtol=0, atol=1e-10)


def test_closed_forms_up_to_l2():
    """The polynomials listed by Sloan ("Stupid SH tricks") / Green, with the signs of this module's convention."""
    w = _dirs(1000, seed=3)
    x, y, z = w.unbind(-1)
    exact = torch.stack([
        torch.full_like(x, 0.5 * math.sqrt(1 / math.pi)),
        math.sqrt(3 / (4 * math.pi)) * y, math.sqrt(3 / (4 * math.pi)) * z, math.sqrt(3 / (4 * math.pi)) * x,
        0.5 * math.sqrt(15 / math.pi) * x * y, 0.5 * math.sqrt(15 / math.pi) * y * z,
        0.25 * math.sqrt(5 / math.pi) * (3 * z * z - 1),
        0.5 * math.sqrt(15 / math.pi) * x * z, 0.25 * math.sqrt(15 / math.pi) * (x * x - y * y),
    ], -1)
    torch.testing.assert_close(real_sh(w, 2), exact, rtol=0, atol=1e-14)
    # the 6-digit constants as printed in the papers
    rounded = torch.stack([
        torch.full_like(x, 0.282095), 0.488603 * y, 0.488603 * z, 0.488603 * x,
        1.092548 * x * y, 1.092548 * y * z, 0.315392 * (3 * z * z - 1), 1.092548 * x * z, 0.546274 * (x * x - y * y),
    ], -1)
    torch.testing.assert_close(real_sh(w, 2), rounded, rtol=0, atol=2e-6)
    # degree-L output is a prefix of any higher degree's
    torch.testing.assert_close(real_sh(w, 5)[:, :9], real_sh(w, 2), rtol=0, atol=0)


@pytest.mark.parametrize("degree", [2, 6, 10])
def test_orthonormal(degree):
    w, weights = _quadrature(degree)
    y = real_sh(w, degree)
    gram = y.T @ (y * weights[:, None])
    torch.testing.assert_close(gram, torch.eye(sh_count(degree), dtype=torch.float64), rtol=0, atol=1e-10)


def test_projection_recovers_coefficients():
    g = torch.Generator().manual_seed(11)
    coeffs = torch.randn(3, 9, generator=g, dtype=torch.float64)  # 3 channels of a degree-2 function
    w, weights = _quadrature(4)
    values = real_sh(w, 2) @ coeffs.T  # (M, 3)
    torch.testing.assert_close(sh_project(values, w, weights, 2), coeffs, rtol=0, atol=1e-12)
    # projecting on more bands gives zeros above l = 2
    high = sh_project(values, w, weights, 4)
    assert high.shape == (3, 25)
    torch.testing.assert_close(high[:, :9], coeffs, rtol=0, atol=1e-12)
    torch.testing.assert_close(high[:, 9:], torch.zeros(3, 16, dtype=torch.float64), rtol=0, atol=1e-12)


def test_monte_carlo_projection():
    """weights = 1 / (pdf N) with the uniform sphere pdf 1 / (4 pi): the estimate converges to the coefficients."""
    coeffs = torch.tensor([[1.0, 0.5, -0.25, 0.3, 0.0, 0.1, -0.2, 0.0, 0.4]], dtype=torch.float64)
    n = 400_000
    w = _dirs(n, seed=5)
    values = real_sh(w, 2) @ coeffs.T
    est = sh_project(values, w, torch.full((n,), 4 * math.pi / n, dtype=torch.float64), 2)
    torch.testing.assert_close(est, coeffs, rtol=0, atol=0.02)


def test_float32_gradients_and_empty():
    w = _dirs(500, seed=9)
    y32 = real_sh(w.float(), 4)
    assert y32.dtype == torch.float32
    torch.testing.assert_close(y32.double(), real_sh(w, 4), rtol=0, atol=1e-5)
    assert real_sh(w[:0], 3).shape == (0, 16)
    assert real_sh(w, 0).shape == (500, 1)
    wg = w[:6].clone().requires_grad_()
    assert torch.autograd.gradcheck(lambda v: real_sh(v, 3), (wg,))
    values = torch.randn(6, 2, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda v: sh_project(v, w[:6], torch.ones(6, dtype=torch.float64), 2), (values,))


def test_sh_count():
    assert [sh_count(d) for d in range(5)] == [1, 4, 9, 16, 25]
    assert sh_count(np.int64(3)) == 16


def test_bad_input():
    w = _dirs(4)
    for degree in (-1, 1.5, True, "2", None):
        with pytest.raises(InputError, match="degree"):
            real_sh(w, degree)
        with pytest.raises(InputError, match="degree"):
            sh_count(degree)
    with pytest.raises(InputError, match="w"):
        real_sh(w[:, :2], 2)
    with pytest.raises(InputError, match="w"):
        real_sh(2 * w, 2)
    with pytest.raises(InputError, match="w"):
        real_sh(torch.tensor([[0.0, float("nan"), 1.0]]), 2)
    with pytest.raises(InputError, match="w"):
        real_sh(w.numpy(), 2)
    with pytest.raises(InputError, match="w"):
        real_sh(torch.tensor([[0, 0, 1]]), 2)
    values, weights = torch.ones(4, 2, dtype=torch.float64), torch.ones(4, dtype=torch.float64)
    with pytest.raises(InputError, match="values"):
        sh_project(values[:, 0], w, weights, 2)
    with pytest.raises(InputError, match="w"):
        sh_project(values, w[:3], weights, 2)
    with pytest.raises(InputError, match="weights"):
        sh_project(values, w, weights[:3], 2)
    with pytest.raises(InputError, match="weights"):
        sh_project(values, w, torch.full((4,), float("inf"), dtype=torch.float64), 2)
    with pytest.raises(InputError, match="values"):
        sh_project(values * float("nan"), w, weights, 2)
    with pytest.raises(InputError, match="degree"):
        sh_project(values, w, weights, -2)
