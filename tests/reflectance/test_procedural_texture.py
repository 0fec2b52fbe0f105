"""Procedural texture sets: canonical materials, drawn variants of each class, seamless tiling, bad input."""
from __future__ import annotations

import pytest
import torch

from neumat import InputError
from neumat.reflectance.procedural_texture import (
    KINDS,
    material_parameters,
    parse_material,
    procedural_texture_set,
)


@pytest.mark.parametrize("kind", KINDS)
def test_variants_are_distinct_reproducible_materials(kind):
    sets = [procedural_texture_set(kind, 32, seed=1, variant=v) for v in range(4)]
    assert [s.name for s in sets] == [kind, f"{kind}~1", f"{kind}~2", f"{kind}~3"]
    for s in sets:
        assert 0 <= float(s.color.min()) and float(s.color.max()) <= 1
        assert 0.05 <= float(s.roughness.min()) and float(s.roughness.max()) <= 1
        assert 0 <= float(s.height.min()) and float(s.height.max()) <= 1
        assert torch.allclose(s.normal.norm(dim=-1), torch.ones(32, 32), atol=1e-5)
    for i in range(4):                       # every pair differs in colour (each variant draws its own)
        for j in range(i):
            assert float((sets[i].color - sets[j].color).abs().max()) > 0.05
    again = procedural_texture_set(kind, 32, seed=1, variant=2)
    assert torch.equal(again.color, sets[2].color) and torch.equal(again.height, sets[2].height)
    assert material_parameters(kind, 2) == material_parameters(kind, 2)


@pytest.mark.parametrize("kind", ["bumps", "weave", "dents", "ridges"])
@pytest.mark.parametrize("variant", [0, 1, 5])
def test_height_tiles_without_a_seam(kind, variant):
    """The jump across the wrap-around edge is no larger than the largest jump between interior neighbours
    (smooth classes; bricks' per-texel noise makes every neighbour jump large)."""
    h = procedural_texture_set(kind, 64, seed=2, variant=variant).height
    for axis in (0, 1):
        inner = h.diff(dim=axis).abs().max()
        seam = (h.select(axis, 0) - h.select(axis, -1)).abs().max()
        assert float(seam) <= float(inner) + 1e-6


def test_bricks_variants_keep_whole_bricks_per_tile():
    for v in range(1, 8):
        p = material_parameters("bricks", v)
        assert p["rows"] % 2 == 0 and p["per_row"] >= 1          # the half-brick offset repeats across the edge


def test_parse_material_and_bad_input():
    assert parse_material("bricks") == ("bricks", 0)
    assert parse_material("ridges~12") == ("ridges", 12)
    for bad in ("velvet", "bricks~x", "bricks~-1", ""):
        with pytest.raises(InputError, match="procedural material"):
            parse_material(bad)
    with pytest.raises(InputError, match="kind"):
        procedural_texture_set("velvet")
    with pytest.raises(InputError, match="variant"):
        procedural_texture_set("bumps", variant=-1)
