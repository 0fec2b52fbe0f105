"""Property-based checks of the Query / Material API (issue 26): random shapes, dtypes, NaN / inf, non-unit and
below-horizon directions, u outside [0, 1). Each call either raises InputError or returns finite values of the
documented shape; a raw torch error is a failure."""
from __future__ import annotations

import math
from collections import Counter

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from neumat.core.errors import InputError
from neumat.core.material import Material
from neumat.core.query import Query, Sample
from neumat.io.merl import MERL_DIMS
from neumat.io.rgl import RglData
from neumat.io.texture_set import TextureSet
from neumat.reflectance.analytic import Principled
from neumat.reflectance.measured import MerlMaterial, RglMaterial
from neumat.reflectance.spec import parse_spec
from neumat.reflectance.svbrdf import SVBRDF


def _checker_svbrdf() -> SVBRDF:
    """A float32 8 x 8 checker of two principled materials with tilted normals."""
    ij = torch.arange(8)
    odd = ((ij[:, None] + ij[None, :]) % 2).float()
    tilt = torch.stack([0.3 * (2 * odd - 1), 0.1 + 0 * odd, torch.ones_like(odd)], -1)
    return SVBRDF(TextureSet(color=torch.stack([0.8 * odd + 0.1, 0.2 + 0 * odd, 0.5 - 0.4 * odd], -1),
                             normal=tilt / tilt.norm(dim=-1, keepdim=True), roughness=0.15 + 0.6 * odd,
                             metalness=odd, height=torch.zeros(8, 8), name="checker"), samples=4)


def _merl() -> MerlMaterial:
    """A smooth synthetic MERL table with 1 % missing (-1) entries, nearest-cell lookup."""
    rng = np.random.default_rng(0)
    table = 500 + 100 * rng.random((3, *MERL_DIMS))
    table[rng.random(table.shape) < 0.01] = -1
    return MerlMaterial(table)


def _rgl() -> RglMaterial:
    """A small synthetic isotropic RGL table (3 incident elevations)."""
    rng = np.random.default_rng(0)
    u = np.linspace(0, 1, 16, dtype=np.float32)
    fields = {"description": np.frombuffer(b"synthetic", np.uint8), "phi_i": np.zeros(1, np.float32),
              "theta_i": np.array([0, 0.7, np.pi / 2], np.float32),
              "ndf": rng.random((2, 8), dtype=np.float32) + 0.1, "sigma": rng.random((2, 8), dtype=np.float32) + 0.5,
              "vndf": (rng.random((1, 3, 16, 16), dtype=np.float32) + 0.5) * u ** 3 * (1 - u) ** 2 + 1e-6,
              "luminance": rng.random((1, 3, 8, 8), dtype=np.float32) + 0.1,
              "rgb": rng.random((1, 3, 3, 8, 8), dtype=np.float32), "jacobian": np.ones(1, np.uint8)}
    return RglMaterial(RglData(fields, "synthetic"))


SPECS = ["lambert", "ggx:roughness=0.3", "plastic", "principled", "svbrdf", "principled-float64", "merl", "rgl"]
MATERIALS = {**{s: parse_spec(s) for s in SPECS[:4]}, "svbrdf": _checker_svbrdf(),
             "principled-float64": Principled(base_color=torch.tensor([0.2, 0.5, 0.9], dtype=torch.float64),
                                              roughness=torch.tensor(0.3, dtype=torch.float64)),
             "merl": _merl(), "rgl": _rgl()}
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


def _query_or_none(wi, wo=None, material: Material | None = None):
    """Query(wi, wo), with uv at fixed texels (in wi's dtype) when `material` is spatially varying; None when
    Query refuses the directions."""
    try:
        uv = None
        if material is not None and material.spatially_varying and wi.is_floating_point():
            uv = torch.linspace(0, 1, wi.shape[0], dtype=torch.float64)[:, None].expand(-1, 2).to(wi.dtype)
        return Query(wi, wo, uv=uv)
    except InputError:
        return None


@SETTINGS
@given(wi=raw_directions(), wo=raw_directions())
def test_query_accepts_valid_directions_or_raises_input_error(wi, wo):
    q = _query_or_none(wi, wo)
    if q is not None:
        assert q.wi.is_floating_point() and torch.isfinite(q.wi).all()
        assert ((q.wi.norm(dim=-1) - 1).abs() <= 1e-3).all()


def _unit(draw, n: int, dtype) -> torch.Tensor:
    theta = draw(st.lists(st.floats(0, math.pi), min_size=n, max_size=n))  # below the horizon too
    phi = draw(st.lists(st.floats(0, 2 * math.pi), min_size=n, max_size=n))
    return torch.tensor([[math.sin(a) * math.cos(b), math.sin(a) * math.sin(b), math.cos(a)]
                         for a, b in zip(theta, phi)], dtype=dtype).reshape(n, 3)


@st.composite
def direction_pairs(draw):
    """(wi, wo): mostly a valid pair (unit, one float dtype and count), else raw ones: the material properties below
    see many valid queries, so that refusing them cannot pass unnoticed."""
    if draw(st.integers(0, 3)) == 0:
        return draw(raw_directions()), draw(raw_directions())
    n, dtype = draw(st.integers(1, 4)), draw(st.sampled_from([torch.float32, torch.float64]))
    return _unit(draw, n, dtype), _unit(draw, n, dtype)


def _mostly_accepted(counts: Counter, what: str) -> None:
    """At least 20 valid draws (of about 45 expected) reached the material, and it refused at most 10 % of them."""
    assert counts["valid"] >= 20 and counts["refused"] <= 0.1 * counts["valid"], (what, dict(counts))


def test_eval_and_pdf_are_finite_and_non_negative():
    """Values of the query's dtype, finite, >= 0 (the synthetic RGL table has no negative entries) and 0 below the
    horizon; a pdf where the material samples."""
    counts = Counter()

    @SETTINGS
    @given(spec=st.sampled_from(SPECS), pair=direction_pairs())
    def check(spec, pair):
        m, (wi, wo) = MATERIALS[spec], pair
        q = _query_or_none(wi, wo, m)
        assume(q is not None)
        counts["valid"] += 1
        try:
            f = m.eval(q)
            pdf = m.pdf(q) if m.can_sample else torch.zeros(len(q), dtype=q.dtype)
        except InputError:
            counts["refused"] += 1
            assume(False)
        assert f.shape == (len(q), 3) and f.dtype == q.dtype, (spec, f.shape, f.dtype, q.dtype)
        assert torch.isfinite(f).all() and (f >= 0).all(), (spec, q.wi, q.wo, f)
        below = (q.wi[:, 2] <= 0) | (q.wo[:, 2] <= 0)
        assert (f[below] == 0).all() and (pdf[below] == 0).all(), (spec, q.wi, q.wo, f, pdf)
        assert pdf.shape == (len(q),) and torch.isfinite(pdf).all() and (pdf >= 0).all()

    check()
    _mostly_accepted(counts, "eval / pdf")


def test_sample_checks_u_and_returns_unit_directions():
    """u outside [0, 1)^2 (or not floating point) is refused; inside, the material samples unit directions."""
    counts = Counter()

    @SETTINGS
    @given(spec=st.sampled_from([s for s in SPECS if MATERIALS[s].can_sample]), pair=direction_pairs(),
           data=st.data())
    def check(spec, pair, data):
        q = _query_or_none(pair[0], material=MATERIALS[spec])
        assume(q is not None)
        if data.draw(st.integers(0, 3)):  # mostly u in [0, 1)^2
            u = torch.tensor(data.draw(st.lists(st.floats(0, 1, exclude_max=True), min_size=2 * len(q),
                                                max_size=2 * len(q))), dtype=q.dtype).reshape(len(q), 2)
        else:
            u = _tensor(data.draw, len(q), 2, data.draw(st.sampled_from([torch.float32, torch.float64, torch.int64])))
        in_range = u.is_floating_point() and bool(((u >= 0) & (u < 1)).all())
        counts["valid"] += in_range
        try:
            s = MATERIALS[spec].sample(q, u)
        except InputError:
            counts["refused"] += in_range
            assume(not in_range)
            return
        assert in_range, f"u = {u} was accepted"
        assert torch.isfinite(s.wo).all() and ((s.wo.norm(dim=-1) - 1).abs() < 1e-3).all()

    check()
    _mostly_accepted(counts, "sample")


def test_lambert_refuses_u_outside_the_unit_square():
    q = Query(torch.tensor([[0.0, 0.0, 1.0]]))
    with pytest.raises(InputError, match=r"u: expected values in \[0, 1\)"):
        MATERIALS["lambert"].sample(q, torch.tensor([[5.25, 0.5]]))
    with pytest.raises(InputError, match="floating-point"):
        Query(torch.tensor([[0, 0, 1]]))


class _SphereSampler(Material):
    """A "BRDF" whose sampler sends 30 % of its samples below the horizon, uniformly, with their pdf (as a
    neural sampler may): its sample() and pdf() agree over the whole sphere."""

    can_sample = True

    def eval(self, q):
        return torch.ones(len(q), 3, dtype=q.dtype)

    def sample(self, q, u):
        from neumat.warp.hemisphere import sample_uniform_hemisphere
        below = u[:, 0] < 0.3
        w = sample_uniform_hemisphere(torch.stack([torch.where(below, u[:, 0] / 0.3, (u[:, 0] - 0.3) / 0.7),
                                                   u[:, 1]], -1))
        w = torch.where(below[:, None], w * torch.tensor([1.0, 1, -1], dtype=w.dtype), w)
        return Sample(w, self.pdf(q.with_wo(w)), torch.ones(len(q), 3, dtype=q.dtype))

    def pdf(self, q):
        return torch.where(q.wo[:, 2] < 0, 0.3, 0.7) / (2 * math.pi)


def test_chi2_material_tests_samplers_over_the_whole_sphere():
    """`neumat check` reported every neural-appearance sampler FAILED (p = 0): it tested the hemisphere only."""
    from neumat.testing.chi2 import chi2_material
    wi = torch.tensor([0.0, 0.6, 0.8])
    assert chi2_material(_SphereSampler(), wi, n_samples=50_000, res=(20, 20))
    hemisphere = chi2_material(_SphereSampler(), wi, n_samples=50_000, res=(10, 20), sphere=False)
    assert not hemisphere and hemisphere.p_value == 0


def test_reflectance_errors_refuse_a_nan_reference():
    from neumat.metrics.hdr import reflectance_errors

    class NaNMaterial(Material):
        name = "nan-material"

        def eval(self, q):
            return torch.full((len(q), 3), float("nan"), dtype=q.dtype)

    with pytest.raises(InputError, match=r"the reference \(nan-material\) returned 192 NaN or infinite value\(s\) "
                                         r"on 64 queries"):
        reflectance_errors(parse_spec("lambert"), NaNMaterial(), n=64)


def test_measured_materials_answer_zero_below_the_horizon():
    """RGL lookups below the horizon raised IndexError (NaN table positions became indices)."""
    from neumat.warp.sphere import sample_uniform_sphere
    g = torch.Generator().manual_seed(0)
    wi, wo = (sample_uniform_sphere(torch.rand(4096, 2, generator=g, dtype=torch.float64)) for _ in range(2))
    below = (wi[:, 2] <= 0) | (wo[:, 2] <= 0)
    for m in (MATERIALS["rgl"], MATERIALS["merl"]):
        f = m.eval(Query(wi, wo))
        assert torch.isfinite(f).all() and (f[below] == 0).all() and (f[~below] > 0).any()
    pdf = MATERIALS["rgl"].pdf(Query(wi, wo))
    assert torch.isfinite(pdf).all() and (pdf[below] == 0).all()


def test_float64_query_on_a_float32_svbrdf():
    m = MATERIALS["svbrdf"]
    assert m.maps.dtype == torch.float32
    wi = torch.tensor([[0.0, 0.6, 0.8]], dtype=torch.float64)
    q = Query(wi, wi * torch.tensor([1.0, -1, 1], dtype=torch.float64), uv=torch.tensor([[0.3, 0.4]],
                                                                                        dtype=torch.float64))
    assert m.eval(q).dtype == m.pdf(q).dtype == m.sampling_features(q).dtype == torch.float64
    assert m.sample(q.with_wo(None), torch.tensor([[0.3, 0.2]], dtype=torch.float64)).weight.dtype == torch.float64


def test_observations_and_recipes_refuse_bad_numbers():
    from dataclasses import replace
    from neumat.fit.recipe import check_recipe
    from neumat.fit.method import recipe_for
    from neumat.fit.translucent_observations import Observations
    up = torch.tensor([[0.0, 0.0, 1.0]]).repeat(3, 1)
    with pytest.raises(InputError, match="Observations.wi: expected unit vectors, 3 of 3"):
        Observations(up, up, up, 0.5 * up, up)
    with pytest.raises(InputError, match="Observations.value has non-finite values"):
        Observations(up, up, up, up, torch.full_like(up, float("nan")))
    recipe = recipe_for("dipole-bssrdf")
    with pytest.raises(InputError, match="Recipe.options\\['validation_fraction'\\]: expected finite"):
        check_recipe(replace(recipe, options={**recipe.options, "validation_fraction": float("nan")}))


@pytest.mark.mitsuba
def test_mitsuba_render_errors_are_the_plugins_own(tmp_path):
    """Dr.Jit wrapped the plugin's InputError in 'RuntimeError: drjit.custom(...): error while performing a custom
    differentiable operation'; loading wrapped it in a traceback quoted in Mitsuba's parser message."""
    from mitsuba_util import mitsuba_or_skip
    mitsuba_or_skip()
    from typer.testing import CliRunner
    from neumat.cli.main import app
    from neumat.integrations import mitsuba as nm

    class Broken(Material):
        name = "broken"

        def eval(self, q):
            raise InputError("broken material: the plugin's own message")

    mi = nm.register()
    scene = mi.load_dict({"type": "scene", "integrator": {"type": "path"},
                          "sensor": {"type": "perspective", "film": {"type": "hdrfilm", "width": 4, "height": 4},
                                     "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 3], target=[0, 0, 0],
                                                                                 up=[0, 1, 0])},
                          "s": {"type": "sphere", "bsdf": nm.bsdf(Broken())}, "e": {"type": "constant"}})
    with pytest.raises(InputError, match="^broken material: the plugin's own message$"):
        nm.render(scene, spp=1)
    (tmp_path / "s.xml").write_text('<scene version="3.0.0"><shape type="sphere"><bsdf type="neumat">'
                                    f'<string name="material" value="{tmp_path / "none.nmat"}"/></bsdf></shape>'
                                    '</scene>')
    r = CliRunner().invoke(app, ["mitsuba-render", str(tmp_path / "s.xml"), "-o", str(tmp_path / "x.png")])
    said = " ".join(r.output.split())
    assert r.exit_code == 2 and "Traceback" not in said and said.endswith("none.nmat' does not exist or is not a "
                                                                          "regular file"), said
