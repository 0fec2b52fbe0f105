"""Real spherical harmonics for precomputed radiance transfer (PRT).

Orthonormal real SH Y_l^m on the unit sphere, in the graphics ordering: coefficient l (l + 1) + m for
m = -l..l, (L + 1)^2 coefficients up to degree L. Convention of Green's "Spherical Harmonic Lighting" (no
Condon-Shortley phase in the real functions), so for w = (x, y, z):

    Y_0^0 = 0.282095,  Y_1^-1 = 0.488603 y,  Y_1^0 = 0.488603 z,  Y_1^1 = 0.488603 x,
    Y_l^m = sqrt(2) K_l^|m| P_l^|m|(z) {cos(m phi) if m > 0, sin(|m| phi) if m < 0},  Y_l^0 = K_l^0 P_l^0(z).

Evaluated without angles: sin^m(theta) cos(m phi) and sin^m(theta) sin(m phi) are Re / Im of (x + i y)^m, and
the normalised Legendre factors K_l^m P_l^m(z) / sin^m(theta) follow the fully normalised three-term recurrence,
which stays stable in float64 to high degree (no factorials). Differentiable with respect to w.
"""
from __future__ import annotations

import math
import operator

import torch

from neumat.core.checks import check_directions, check_finite, check_shape
from neumat.core.errors import InputError


def sh_count(degree: int) -> int:
    """Number of real SH coefficients up to `degree` inclusive: (degree + 1)^2."""
    return (_check_degree(degree) + 1) ** 2


def real_sh(w: torch.Tensor, degree: int) -> torch.Tensor:
    """Real orthonormal SH basis at unit directions w (N, 3) -> (N, (degree + 1)^2), index l (l + 1) + m."""
    degree = _check_degree(degree)
    check_shape(w, "w", (-1, 3))
    if not w.is_floating_point():
        raise InputError(f"w: expected a floating-point tensor, got {w.dtype}")
    check_directions(w, "w")
    x, y, z = w.unbind(-1)
    out: list[torch.Tensor | None] = [None] * (degree + 1) ** 2
    cos_m, sin_m = torch.ones_like(x), torch.zeros_like(x)  # Re, Im of (x + i y)^m
    q_mm = torch.full_like(z, math.sqrt(1 / (4 * math.pi)))  # K_m^m P_m^m / sin^m, as a (N,) tensor
    for m in range(degree + 1):
        if m > 0:
            cos_m, sin_m = x * cos_m - y * sin_m, x * sin_m + y * cos_m
            q_mm = q_mm * math.sqrt((2 * m + 1) / (2 * m))
        q_prev, q = None, q_mm
        for l in range(m, degree + 1):  # noqa: E741
            if l == m + 1:
                q_prev, q = q, math.sqrt(2 * m + 3) * z * q
            elif l > m + 1:
                a = math.sqrt((4 * l * l - 1) / (l * l - m * m))
                b = math.sqrt(((l - 1) ** 2 - m * m) / (4 * (l - 1) ** 2 - 1))
                q_prev, q = q, a * (z * q - b * q_prev)
            if m == 0:
                out[l * (l + 1)] = q
            else:
                out[l * (l + 1) + m] = math.sqrt(2) * q * cos_m
                out[l * (l + 1) - m] = math.sqrt(2) * q * sin_m
    return torch.stack(out, -1)


def sh_project(values: torch.Tensor, w: torch.Tensor, weights: torch.Tensor, degree: int) -> torch.Tensor:
    """SH coefficients (C, (degree + 1)^2) = sum_j values_j Y(w_j) weights_j.

    values (N, C) are function samples at unit directions w (N, 3); weights (N,) are quadrature weights in
    steradians, or 1 / (pdf(w_j) N) for a Monte Carlo estimate with solid-angle pdf.
    """
    check_shape(values, "values", (-1, -1))
    n = values.shape[0]
    check_shape(w, "w", (n, 3))
    check_shape(weights, "weights", (n,))
    check_finite(values, "values")
    check_finite(weights, "weights")
    basis = real_sh(w, degree)
    return values.to(basis.dtype).T @ (basis * weights.to(basis.dtype)[:, None])


def _check_degree(degree) -> int:
    """Return `degree` as int; raise InputError unless it is an integer >= 0 (bools and floats are refused)."""
    try:
        d = operator.index(degree)
    except TypeError:
        d = None
    if d is None or isinstance(degree, bool) or d < 0:
        raise InputError(f"degree: expected an integer >= 0, got {degree!r}")
    return d
