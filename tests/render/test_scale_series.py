import pytest

from neumat.core.errors import InputError
from neumat.reflectance.procedural_texture import procedural_texture_set
from neumat.reflectance.svbrdf import SVBRDF
from neumat.render.scale_series import plane_scales, score_scale_series, texels_per_pixel
from neumat.catalog.open_material import open_material


def test_plane_scales_span_an_eighth_texel_to_two_textures_per_pixel():
    scales = plane_scales(5, 48, 64)
    tpp = texels_per_pixel(scales, 48, 64)
    assert tpp[0] == pytest.approx(1 / 8) and tpp[-1] == pytest.approx(2 * 64)
    ratios = [b / a for a, b in zip(tpp, tpp[1:])]
    assert ratios == pytest.approx([ratios[0]] * 4)            # geometric
    with pytest.raises(InputError, match="plane_scales"):
        plane_scales(0, 48, 64)


def test_scale_series_scores_a_wrong_material_above_the_reference_noise_floor():
    """A second, better-sampled copy of the reference scores near the reference's own noise floor; a flat grey
    Lambertian is far above it at every scale; lists have one entry per scale."""
    textures = procedural_texture_set("bumps", size=16)
    reference = SVBRDF(textures, samples=8, seed=1)
    opts = dict(n_scales=2, resolution=8, lights=["dir:0.3/1/0.2"], tilts=[35.0])
    same = score_scale_series(SVBRDF(textures, samples=64, seed=2), reference, **opts)
    grey = score_scale_series(open_material("lambert:albedo=0.5"), reference, **opts)
    for s in (same, grey):
        assert len(s["flip"]) == len(s["floor"]) == len(s["texels_per_pixel"]) == 2
        assert s["flip_mean"] == pytest.approx(sum(s["flip"]) / 2)
    assert same["flip_mean"] < 1.5 * same["floor_mean"]
    assert all(g > 3 * f for g, f in zip(grey["flip"], grey["floor"]))


def test_scale_series_needs_a_textured_reference():
    with pytest.raises(InputError, match="textured reference"):
        score_scale_series(open_material("lambert:albedo=0.5"), open_material("lambert:albedo=0.4"), n_scales=1,
                           resolution=8)
