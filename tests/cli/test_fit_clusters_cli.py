"""`neumat fit-clusters` through typer's CliRunner on a local app: the files it writes, clusters.json against
`cluster_materials` on the same inputs and seed, separable material families in separate clusters, members that
`neumat eval --member` scores as clusters.json says, and bad input refused with one clear line."""
from __future__ import annotations

import json

import numpy as np
import pytest
import typer
from typer.testing import CliRunner

from neumat.catalog.modelfile import load_model
from neumat.catalog.open_material import open_material
from neumat.cli import fit_clusters, fitting
from neumat.methods.neubrdf.shared_targets import cluster_materials
from neumat.methods.neubrdf.shared_model import SharedNeuBRDF

from cli_util import output_text

#: two diffuse-dominated plastics and two coloured metals (sharp GGX): separable families
PLASTICS = ["plastic:diffuse=0.6/0.3/0.15,roughness=0.4", "plastic:diffuse=0.3/0.5/0.4,roughness=0.5"]
METALS = ["ggx:roughness=0.15,fresnel=schlick,f0=0.95/0.8/0.5", "ggx:roughness=0.2,fresnel=schlick,f0=0.9/0.9/0.9"]
SOURCES = [PLASTICS[0], METALS[0], PLASTICS[1], METALS[1]]
#: the autoencoder's sizes (as the Python clustering test) and a tiny shared model
CLUSTER = dict(resolution=8, code_dim=4, width=8, steps=150)
SMALL = ["--set", "nside=2", "--set", "index_bits=3", "--set", "hidden=8", "--set", "batch_size=64",
         *[a for k, v in CLUSTER.items() for a in ("--set", f"cluster_{k}={v}")], "--device", "cpu", "-q"]


@pytest.fixture
def app() -> typer.Typer:
    app = typer.Typer(pretty_exceptions_enable=False, add_completion=False)
    fit_clusters.register(app)
    fitting.register(app)
    return app


def test_fit_clusters_writes_one_model_per_cluster_as_cluster_materials_groups(app, tmp_path):
    out = tmp_path / "run"
    res = CliRunner().invoke(app, ["fit-clusters", *SOURCES, "-k", "2", *SMALL, "--steps", "4", "--seed", "5",
                                   "--n-configs", "4096", "-o", str(out)])
    assert res.exit_code == 0, res.output
    summary = json.loads((out / "clusters.json").read_text())
    rows = summary["materials"]
    assert list(rows) == SOURCES

    ref = cluster_materials([open_material(s) for s in SOURCES], 2, seed=5, **CLUSTER)
    # the same partition, clusters numbered in the order of their first source
    assert sorted(sorted(SOURCES.index(s) for s in SOURCES if rows[s]["cluster"] == c) for c in (0, 1)) \
        == sorted(ref.groups)
    first = [rows[s]["cluster"] for s in SOURCES]
    assert list(dict.fromkeys(first)) == [0, 1]
    np.testing.assert_allclose([rows[s]["code"] for s in SOURCES], ref.codes, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose([rows[s]["reconstruction_mse"] for s in SOURCES], ref.errors, rtol=1e-5)
    assert summary["clustering"]["seed"] == 5 and summary["k"] == 2
    # the two families land in different clusters
    assert rows[PLASTICS[0]]["cluster"] == rows[PLASTICS[1]]["cluster"] != rows[METALS[0]]["cluster"] \
        == rows[METALS[1]]["cluster"]

    assert sorted(p.name for p in out.iterdir()) == ["cluster0.nmat", "cluster1.nmat", "clusters.json"]
    for c in summary["clusters"]:
        model = load_model(out / c["nmat"])
        members = [s for s in SOURCES if rows[s]["cluster"] == c["cluster"]]
        assert isinstance(model, SharedNeuBRDF) and model.cfg.num_materials == len(members) == 2
        assert c["sources"] == members and sorted(rows[s]["member"] for s in members) == [0, 1]
        assert c["bytes_fp16"] == model.size_bytes("fp16") and c["steps"] == 4
        assert all(rows[s]["bytes_fp16"] == model.size_bytes("fp16") / 2 for s in members)
    assert "cluster" in res.stdout and "wrote 2 model(s)" in output_text(res)

    # `neumat eval --member` on a written member gives the errors clusters.json recorded for it
    row = rows[METALS[1]]
    res = CliRunner().invoke(app, ["eval", str(out / row["nmat"]), "--member", str(row["member"]), "--against",
                                   METALS[1], "--no-image", "--json", "--n-configs", "4096", "--device", "cpu"])
    assert res.exit_code == 0, res.output
    scored = json.loads(res.stdout)
    for key in ("rmse_hdr", "log_err", "rel_err"):
        assert scored[key] == pytest.approx(row["metrics"][key], rel=1e-9)


def test_every_source_a_cluster_of_its_own_and_a_rerun_with_fewer_clusters_removes_the_stale_model(app, tmp_path):
    res = CliRunner().invoke(app, ["fit-clusters", PLASTICS[0], METALS[0], "-k", "2", *SMALL, "--steps", "2",
                                   "--n-configs", "0", "-o", str(tmp_path / "run")])
    assert res.exit_code == 0, res.output
    summary = json.loads((tmp_path / "run" / "clusters.json").read_text())
    assert sorted(len(c["members"]) for c in summary["clusters"]) == [1, 1]
    assert all(r["member"] == 0 and r["metrics"] == {} for r in summary["materials"].values())
    (tmp_path / "run" / "notes.txt").write_text("kept")
    res = CliRunner().invoke(app, ["fit-clusters", PLASTICS[0], METALS[0], "-k", "1", *SMALL, "--steps", "2",
                                   "--n-configs", "0", "-o", str(tmp_path / "run")])
    assert res.exit_code == 0, res.output
    assert sorted(p.name for p in (tmp_path / "run").iterdir()) == ["cluster0.nmat", "clusters.json", "notes.txt"]
    assert "removed 1 model(s) of an earlier run with more clusters: cluster1.nmat" in output_text(res)


def _texture_set(folder):
    from PIL import Image
    folder.mkdir()
    Image.new("RGB", (4, 4), (200, 30, 30)).save(folder / "x_Color.png")
    Image.new("RGB", (4, 4), (128, 128, 255)).save(folder / "x_NormalGL.png")
    Image.new("L", (4, 4), 128).save(folder / "x_Roughness.png")
    return folder


@pytest.mark.parametrize("case", ["k_too_large", "svbrdf", "num_materials", "unknown_key", "out_is_file",
                                  "missing_file"])
def test_bad_input_is_one_clear_error(app, tmp_path, case):
    sources, extra, out = SOURCES[:3], [], tmp_path / "run"
    expected = {"k_too_large": "-k 4: more clusters than materials; expected at most 3",
                "svbrdf": "is spatially varying", "num_materials": "--set num_materials",
                "unknown_key": "unknown key 'cluster_step' of shared-neubrdf (did you mean option.cluster_steps",
                "out_is_file": "is a file; expected a folder",
                "missing_file": "does not exist"}[case]
    k = "4" if case == "k_too_large" else "2"
    if case == "svbrdf":
        sources = [*sources, str(_texture_set(tmp_path / "fabric"))]
    elif case in ("num_materials", "unknown_key"):
        extra = ["--set", "num_materials=3" if case == "num_materials" else "cluster_step=3"]
    elif case == "out_is_file":
        out.write_text("x")
    elif case == "missing_file":
        sources = [*sources, str(tmp_path / "nothing.binary")]
    res = CliRunner().invoke(app, ["fit-clusters", *sources, "-k", k, *SMALL, *extra, "--steps", "2",
                                   "-o", str(out)])
    assert res.exit_code == 2, res.output
    assert "error:" in res.output and expected in output_text(res)
    if case == "svbrdf":
        assert "fabric" in output_text(res)
    assert case == "out_is_file" or not out.exists()  # refused before any file is written
