"""`neumat list`: every registered model with its paper, source kinds, recipe and exports; sources; exporters."""
from __future__ import annotations

import json

from typer.testing import CliRunner

from neumat.cli.main import app
from neumat.models.registry import load_all


def test_list_json_has_every_model_with_a_recipe():
    res = CliRunner().invoke(app, ["list", "--json"])
    assert res.exit_code == 0, res.output
    data = json.loads(res.output)
    models = {m["name"]: m for m in data["models"]}
    assert set(models) == set(load_all().names())
    assert all(m["recipe"] is True and m["steps"] > 0 and m["paper"] and m["source_kinds"] for m in models.values())
    assert models["neubrdf"]["exports"] == ["drjit", "glsl", "slang", "web"] and models["ggx"]["exports"] == ["drjit"]
    assert models["neural-appearance"]["exports"] == ["drjit", "glsl", "slang", "web"]
    assert "drjit" not in models["neumip-uv"]["exports"]  # a format lists only the models it takes
    assert models["neural-appearance"]["phase_split"] == [0.5, 0.5]
    assert {".binary", ".bsdf", ".nmat", ".nbtf", ".json", "folder", "spec"} <= {s["key"] for s in data["sources"]}
    assert {e["name"] for e in data["exporters"]} == {"drjit", "glsl", "slang", "web"}
    assert set(data["source_kinds"]) >= {m for ms in models.values() for m in ms["source_kinds"]}
    # the texture-set and BRDF defaults (neumat.cli.fitting.DEFAULT_MODELS) say why in their "measured" line
    assert models["multiscale"]["measured"].startswith("the default for texture sets")
    assert models["neubrdf"]["measured"].startswith("the default for BRDFs")
    assert "dielectric" in models["tripleplane"]["measured"] and "Wood092" in models["tripleplane"]["measured"]
    assert models["ggx"]["measured"] == ""


def test_list_tables_fit_80_columns():
    res = CliRunner().invoke(app, ["list"], env={"COLUMNS": "80"})
    assert res.exit_code == 0, res.output
    assert "neural-appearance" in res.output and max(map(len, res.output.splitlines())) <= 80
