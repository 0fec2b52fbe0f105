"""Property-based checks of the Query / Material API (issue 26): random shapes, dtypes, NaN / inf, non-unit and
below-horizon directions, u outside [0, 1). Each call either raises InputError or returns finite values of the
documented shape; a raw torch error is a failure."""
from __future__ import annotations

import math

import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from neumat.core.errors import InputError
from neumat.core.query import Query
from neumat.reflectance.spec import parse_spec

SPECS = ["lambert", "ggx:roughness=0.3", "plastic", "principled"]
MATERIALS = {s: parse_spec(s) for s in SPECS}
FLOATS = st.floats(allow_nan=True, allow_infinity=True, width=32)
SETTINGS = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def _tensor(draw, n: int, k: int, dtype) -> torch.Tensor:
    return torch.tensor(draw(st.lists(st.lists(FLOATS, min_size=k, max_size=k), min_size=n, max_size=n)),
                        dtype=torch.float64).reshape(n, k).to(dtype)


@st.composite
def raw_directions(draw):
    """(N, k) tensors of any dtype and values: mostly unit vectors, some not, some NaN / inf, some ints."""
    n, k = draw(st.integers(0, 4)), draw(st.sampled_from([3, 3, 3, 2, 4]))
    dtype = draw(st.sampled_from([torch.float32, torch.float64, torch.float16, torch.int64]))
    if draw(st.booleans()):
        theta = draw(st.lists(st.floats(0, math.pi), min_size=n, max_size=n))  # below the horizon too
        phi = draw(st.lists(st.floats(0, 2 * math.pi), min_size=n, max_size=n))
        t = torch.tensor([[math.sin(a) * math.cos(b), math.sin(a) * math.sin(b), math.cos(a)]
                          for a, b in zip(theta, phi)], dtype=torch.float64).reshape(n, 3)
        return t[:, :k].to(dtype) if k <= 3 else t.to(dtype)
    return _tensor(draw, n, k, dtype)


def _query_or_none(wi, wo=None):
    try:
        return Query(wi, wo)
    except InputError:
        return None


@SETTINGS
@given(wi=raw_directions(), wo=raw_directions())
def test_query_accepts_valid_directions_or_raises_input_error(wi, wo):
    q = _query_or_none(wi, wo)
    if q is not None:
        assert q.wi.is_floating_point() and torch.isfinite(q.wi).all()
        assert ((q.wi.norm(dim=-1) - 1).abs() <= 1e-3).all()


@SETTINGS
@given(spec=st.sampled_from(SPECS), wi=raw_directions(), wo=raw_directions())
def test_eval_and_pdf_are_finite_and_non_negative(spec, wi, wo):
    q = _query_or_none(wi, wo)
    if q is None:
        return
    m = MATERIALS[spec]
    try:
        f, pdf = m.eval(q), m.pdf(q)
    except InputError:
        return
    assert f.shape == (len(q), 3) and torch.isfinite(f).all() and (f >= 0).all(), (spec, q.wi, q.wo, f)
    assert pdf.shape == (len(q),) and torch.isfinite(pdf).all() and (pdf >= 0).all()


@SETTINGS
@given(spec=st.sampled_from(SPECS), wi=raw_directions(), data=st.data())
def test_sample_checks_u_and_returns_unit_directions(spec, wi, data):
    q = _query_or_none(wi)
    if q is None:
        return
    u = _tensor(data.draw, len(q), 2, data.draw(st.sampled_from([torch.float32, torch.float64, torch.int64])))
    in_range = u.is_floating_point() and bool(((u >= 0) & (u < 1)).all())
    try:
        s = MATERIALS[spec].sample(q, u)
    except InputError:
        return
    assert in_range, f"u = {u} was accepted"
    assert torch.isfinite(s.wo).all() and ((s.wo.norm(dim=-1) - 1).abs() < 1e-3).all()


def test_lambert_refuses_u_outside_the_unit_square():
    q = Query(torch.tensor([[0.0, 0.0, 1.0]]))
    with pytest.raises(InputError, match=r"u: expected values in \[0, 1\)"):
        MATERIALS["lambert"].sample(q, torch.tensor([[5.25, 0.5]]))
    with pytest.raises(InputError, match="floating-point"):
        Query(torch.tensor([[0, 0, 1]]))
