"""Mitsuba's chi-square test of NeuPreSS's incident-direction sampler on the Dr.Jit runtime (program "neupress",
`neumat.export.drjit.neupress`): the directions `sample_incident` draws, and those of the `lobe` object the native
scene integrator (`neumat.integrations.mitsuba_translucent`, `_subsurface_native`) samples and weighs with, against
`incident_pdf` / `lobe.pdf` over the whole sphere, for narrow, medium and wide (truncated at pi) lobes about tilted
normals. A pdf of a slightly wider lobe is rejected, so the test can fail."""
from __future__ import annotations

import math

import numpy as np
import pytest

from test_mitsuba_native_translucent import _model, mi  # noqa: F401  (mi: a fixture)

pytestmark = pytest.mark.mitsuba

#: (object-space position x, view wo, normal n, the range the lobe's sigma (radians) falls in at that query)
CASES = {
    "narrow": ((0.78, -0.1, 0.6), (-0.3, -0.9, -0.3), (0.3, -0.5, 0.8), (0.1, 0.4)),
    "medium": ((0.54, 0.49, 0.19), (0.63, -0.59, 0.5), (-0.9, 0.2, 0.1), (0.6, 1.6)),
    "wide": ((-0.41, 0.3, -0.84), (0.59, 0.81, -0.08), (0.1, 0.6, -0.7), (2.0, 5.0)),
}


def _unit(v) -> list[float]:
    a = np.asarray(v, np.float64)
    return (a / np.linalg.norm(a)).tolist()


@pytest.fixture(scope="module")
def runtime(mi, tmp_path_factory):  # noqa: F811  (the imported fixture)
    """The drjit export of test_mitsuba_native_translucent's small NeuPreSS (sigma over its whole range), loaded."""
    from neumat.export.drjit.runtime import load_runtime
    from neumat.export.registry import load_formats
    fmt = load_formats().get("drjit")
    folder, _ = fmt.write(fmt.export(_model(), "fp32"), tmp_path_factory.mktemp("neupress"))
    return load_runtime(folder, mi.Float)


def _chi2(mi, rt, case: str, via: str, pdf_scale_sigma: float = 1.0):  # noqa: F811
    """Mitsuba's ChiSquareTest of the sampler (`via` "runtime": sample_incident / incident_pdf; "lobe": the lobe
    object the integrator uses) at one query, all lanes sharing it; `pdf_scale_sigma` widens the lobe whose pdf is
    compared (1: the sampler's own)."""
    from neumat.export.drjit.neupress import Lobe
    x, wo, n, _ = CASES[case]
    x, wo, n = mi.Point3f(*x), mi.Vector3f(*_unit(wo)), mi.Vector3f(*_unit(n))

    def sample(s):
        if via == "runtime":
            wi, _ = rt.sample_incident(x, wo, n, s.x, s.y)
            return wi
        w, _ = rt.lobe(x, wo, n).sample(s.x, s.y)
        return mi.Vector3f(*w)

    def pdf(w):
        if pdf_scale_sigma != 1.0:
            lobe = rt.lobe(x, wo, n)
            return Lobe(lobe.axis, lobe.sigma * pdf_scale_sigma).pdf([w.x, w.y, w.z])
        if via == "runtime":
            return rt.incident_pdf(w, x, wo, n)
        return rt.lobe(x, wo, n).pdf([w.x, w.y, w.z])

    return mi.chi2.ChiSquareTest(domain=mi.chi2.SphericalDomain(), sample_func=sample, pdf_func=pdf, sample_dim=2,
                                 sample_count=200_000, res=32, ires=8)


@pytest.mark.parametrize("via", ["runtime", "lobe"])
@pytest.mark.parametrize("case", list(CASES))
def test_mitsuba_chi2_accepts_the_runtime_incident_sampler(mi, runtime, case, via, monkeypatch, tmp_path):  # noqa: F811
    monkeypatch.chdir(tmp_path)  # a rejected test writes chi2_data.py into the working directory
    x, wo, _, (lo, hi) = CASES[case]
    sigma = float(np.array(runtime.sigma(mi.Point3f(*x), mi.Vector3f(*_unit(wo))))[0])
    assert lo < sigma < hi, sigma  # the query gives the lobe width it stands for
    test = _chi2(mi, runtime, case, via)
    ok = test.run()
    print(f"sigma {sigma:.3f} p-value {float(test.p_value):.3g}", end=" ")
    assert ok, test.messages
    # the pdf integrates to 1 over the sphere (up to the trapezoid rule at the antipode, where the lobe's r / sin r
    # diverges: 2.0e-3 off for the wide lobe, 3.2e-4 for the medium one)
    assert math.isclose(float(test.pdf_sum[0]), 1.0, abs_tol=5e-3), test.messages


@pytest.mark.parametrize("case", ["narrow", "wide"])
def test_mitsuba_chi2_rejects_the_pdf_of_a_wider_lobe(mi, runtime, case, monkeypatch, tmp_path):  # noqa: F811
    """The test has the power to tell: the pdf of a lobe 10% wider than the one sampled fails it."""
    monkeypatch.chdir(tmp_path)
    test = _chi2(mi, runtime, case, "runtime", pdf_scale_sigma=1.1)
    assert not test.run(quiet=True), test.messages
