"""The shipped chi-square tester: it passes correct samplers, is calibrated, and fails wrong ones."""
import math
from dataclasses import replace

import numpy as np
import pytest
import torch
from scipy import stats

from neumat import InputError, Material, Query, Sample
from neumat.core.material import sample_weight
from neumat.testing.chi2 import Chi2Result, chi2_2d, chi2_directions, chi2_material
from neumat.warp import (Tabulated2D, concentric_disk_pdf, cosine_hemisphere_pdf, sample_concentric_disk,
                         sample_cosine_hemisphere, sample_uniform_hemisphere, sample_uniform_sphere,
                         sample_vmf, uniform_hemisphere_pdf, uniform_sphere_pdf, vmf_pdf)


def _all_valid(sample):
    return lambda u: (sample(u), torch.ones(len(u), dtype=torch.bool))


class _Lambert(Material):
    """Diffuse test material with cosine sampling; `wrong_pdf` makes pdf() report the uniform density."""

    can_sample = True

    def __init__(self, wrong_pdf=False):
        self.wrong_pdf = wrong_pdf

    def eval(self, q):
        return torch.full((len(q), 3), 0.5 / math.pi, dtype=q.dtype) * (q.wo[:, 2:] > 0)

    def sample(self, q, u):
        wo = sample_cosine_hemisphere(u)
        pdf = cosine_hemisphere_pdf(wo)
        valid = (q.wi[:, 2] > 0) & (pdf > 0)
        return Sample(wo, torch.where(valid, pdf, torch.zeros_like(pdf)),
                      sample_weight(self.eval(q.with_wo(wo)), wo, pdf, valid))

    def pdf(self, q):
        return (uniform_hemisphere_pdf if self.wrong_pdf else cosine_hemisphere_pdf)(q.wo)


class _UvLambert(_Lambert):
    """Needs Query.uv, to check that chi2_material forwards the template's fields."""

    spatially_varying = True

    def sample(self, q, u):
        q.require("uv")
        return super().sample(q, u)

    def pdf(self, q):
        q.require("uv")
        return super().pdf(q)


class _LyingLambert(_Lambert):
    """Samples correctly but reports twice the true pdf from sample()."""

    def sample(self, q, u):
        s = super().sample(q, u)
        return replace(s, pdf=2 * s.pdf)


def test_correct_samplers_pass():
    r = chi2_directions(_all_valid(sample_cosine_hemisphere), cosine_hemisphere_pdf, n_samples=100_000)
    assert isinstance(r, Chi2Result) and r and r.passed and r.p_value > 0.01
    assert abs(r.pdf_integral - 1) < 1e-6 and r.dof > 100 and "invalid samples = 0/100000" in r.message


def test_wrong_pdf_fails():
    r = chi2_directions(_all_valid(sample_cosine_hemisphere), uniform_hemisphere_pdf, n_samples=100_000)
    assert not r and r.p_value < 1e-12 and r.message.startswith("FAILED")


def test_subtly_wrong_lobe_fails():
    mu = torch.tensor([0.0, 0.6, 0.8])
    r = chi2_directions(_all_valid(lambda u: sample_vmf(u, mu, 20.0)), lambda w: vmf_pdf(w, mu, 21.0),
                        n_samples=100_000, sphere=True)
    assert not r and r.p_value < 1e-6


def test_is_calibrated_under_the_null():
    # p-values of a correct sampler are uniform: KS test over 60 independent seeds
    p = [chi2_directions(_all_valid(sample_uniform_hemisphere), uniform_hemisphere_pdf, n_samples=5_000,
                         res=(8, 16), seed=s).p_value for s in range(60)]
    assert stats.kstest(p, "uniform").pvalue > 1e-3


def test_invalid_samples_are_missing_mass():
    def truncated(u):  # uniform sphere, samples below the horizon fail
        w = sample_uniform_sphere(u)
        return w, w[:, 2] > 0

    r = chi2_directions(truncated, uniform_sphere_pdf, n_samples=100_000)
    assert r, r.message
    assert abs(r.pdf_integral - 0.5) < 1e-6

    def drops_too_much(u):
        w = sample_uniform_sphere(u)
        return w, w[:, 2] > 0.05

    r = chi2_directions(drops_too_much, uniform_sphere_pdf, n_samples=100_000)
    assert not r


def test_samples_outside_domain_and_excess_mass_fail():
    r = chi2_directions(_all_valid(sample_uniform_sphere), uniform_sphere_pdf, n_samples=20_000)
    assert not r and "outside the domain" in r.message
    r = chi2_directions(_all_valid(sample_cosine_hemisphere), lambda w: 1.2 * cosine_hemisphere_pdf(w),
                        n_samples=20_000)
    assert not r and "integrates to 1.2" in r.message and abs(r.pdf_integral - 1.2) < 1e-5


def test_sidak_threshold():
    r = chi2_directions(_all_valid(sample_uniform_hemisphere), uniform_hemisphere_pdf, n_samples=10_000,
                        n_tests=10, alpha=0.01)
    assert f"threshold {1 - 0.99 ** 0.1:.3g}" in r.message


def test_dump_on_failure(tmp_path, monkeypatch):
    r = chi2_directions(_all_valid(sample_cosine_hemisphere), uniform_hemisphere_pdf, n_samples=20_000,
                        dump_dir=tmp_path / "a")
    for name in ("chi2_observed.npy", "chi2_expected.npy", "chi2.png"):
        assert (tmp_path / "a" / name).is_file() and name in r.message
    obs = np.load(tmp_path / "a" / "chi2_observed.npy")
    assert obs.shape == (40, 80) and obs.sum() == 20_000
    monkeypatch.setenv("NEUMAT_CHI2_DUMP", str(tmp_path / "b"))
    chi2_directions(_all_valid(sample_cosine_hemisphere), uniform_hemisphere_pdf, n_samples=20_000)
    assert (tmp_path / "b" / "chi2.png").is_file()


def test_chi2_2d_square_and_disk():
    g = torch.Generator().manual_seed(0)
    t = Tabulated2D(torch.rand(8, 8, generator=g) + 0.1)
    assert chi2_2d(lambda u: t.sample(u)[0], t.pdf, n_samples=100_000, res=(16, 16))
    wrong = Tabulated2D(torch.rand(8, 8, generator=g) + 0.1)
    assert not chi2_2d(lambda u: t.sample(u)[0], wrong.pdf, n_samples=100_000, res=(16, 16))
    assert chi2_2d(sample_concentric_disk, concentric_disk_pdf, n_samples=50_000, domain="disk")
    # uniform square points are not uniform on the disk
    assert not chi2_2d(lambda u: 2 * u - 1, concentric_disk_pdf, n_samples=50_000, domain="disk")


def test_chi2_material():
    wi = torch.tensor([0.0, 0.6, 0.8])
    assert chi2_material(_Lambert(), wi, n_samples=100_000)
    assert not chi2_material(_Lambert(wrong_pdf=True), wi, n_samples=100_000)
    template = Query(wi=wi[None], uv=torch.tensor([[0.25, 0.75]]))
    assert chi2_material(_UvLambert(), wi, n_samples=50_000, template=template)
    # pdf() right, but sample() reports a wrong pdf: the histogram passes, the consistency check fails
    r = chi2_material(_LyingLambert(), wi, n_samples=20_000)
    assert not r and "differs from pdf(wo)" in r.message
    # wi below the horizon: every sample fails and the pdf claims mass -> failure
    assert not chi2_material(_Lambert(), torch.tensor([0.0, 0.0, -1.0]), n_samples=20_000)


def test_bad_input():
    f = _all_valid(sample_uniform_hemisphere)
    with pytest.raises(InputError, match="res"):
        chi2_directions(f, uniform_hemisphere_pdf, res=(0, 4))
    with pytest.raises(InputError, match="n_samples"):
        chi2_directions(f, uniform_hemisphere_pdf, n_samples=0)
    with pytest.raises(InputError, match="alpha"):
        chi2_directions(f, uniform_hemisphere_pdf, alpha=2.0)
    with pytest.raises(InputError, match="domain"):
        chi2_2d(sample_concentric_disk, concentric_disk_pdf, domain="annulus")
    with pytest.raises(InputError, match="pdf_fn"):
        chi2_directions(f, lambda w: -uniform_hemisphere_pdf(w), n_samples=100)
    with pytest.raises(InputError, match="can_sample"):
        chi2_material(Material(), torch.tensor([0.0, 0.0, 1.0]))
    with pytest.raises(InputError, match="wi"):
        chi2_material(_Lambert(), torch.tensor([[0.0, 0.0, 1.0]]))
    with pytest.raises(InputError, match="template"):
        chi2_material(_Lambert(), torch.tensor([0.0, 0.0, 1.0]), template=Query(wi=torch.eye(3)))


@pytest.mark.slow
@pytest.mark.parametrize("name", ["uniform_hemisphere", "cosine_hemisphere", "uniform_sphere", "vmf",
                                  "disk", "tabulated"])
def test_warps_with_2m_samples(name):
    mu = torch.tensor([0.48, -0.6, 0.64])
    t = Tabulated2D(torch.rand(16, 32, generator=torch.Generator().manual_seed(1)) ** 3)
    runs = {
        "uniform_hemisphere": lambda: chi2_directions(_all_valid(sample_uniform_hemisphere), uniform_hemisphere_pdf,
                                                      n_samples=2_000_000, n_tests=6),
        "cosine_hemisphere": lambda: chi2_directions(_all_valid(sample_cosine_hemisphere), cosine_hemisphere_pdf,
                                                     n_samples=2_000_000, n_tests=6),
        "uniform_sphere": lambda: chi2_directions(_all_valid(sample_uniform_sphere), uniform_sphere_pdf,
                                                  n_samples=2_000_000, sphere=True, n_tests=6),
        "vmf": lambda: chi2_directions(_all_valid(lambda u: sample_vmf(u, mu, 40.0)), lambda w: vmf_pdf(w, mu, 40.0),
                                       n_samples=2_000_000, sphere=True, res=(100, 200), n_tests=6),
        "disk": lambda: chi2_2d(sample_concentric_disk, concentric_disk_pdf, n_samples=2_000_000, domain="disk",
                                n_tests=6),
        "tabulated": lambda: chi2_2d(lambda u: t.sample(u)[0], t.pdf, n_samples=2_000_000, res=(64, 32),
                                     n_tests=6),
    }
    r = runs[name]()
    assert r, r.message
