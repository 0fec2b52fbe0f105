import re

from typer.testing import CliRunner

from neumat.cli.main import app
from neumat.catalog.modelfile import load_model


def test_fit_multiscale_on_a_texture_set_folder(shared_data, tmp_path):
    """`neumat fit <texture-set folder> --model multiscale -o x.nmat` with a tiny budget; the saved model
    reloads as the gated model and evaluates (the texture-set folder opens as an SVBRDF)."""
    out = tmp_path / "wood.nmat"
    folder = shared_data / "svbrdf" / "Wood092_1K"
    args = ["fit", str(folder), "--model", "multiscale", "-o", str(out), "--steps", "2", "--quiet", "--device", "cpu",
            "--set", "spatial_size=16", "--set", "batch_size=64"]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    model = load_model(out)
    assert model.name == "multiscale" and model.cfg.spatial_size == 16 and model.spatially_varying
    bound = model.output_bound_values()
    assert bound is not None and f"bounded by the largest target the fit saw: {bound[0]:.4g}" in result.output


def test_fit_rejects_unknown_model_option(shared_data, tmp_path):
    folder = shared_data / "svbrdf" / "Wood092_1K"
    result = CliRunner().invoke(app, ["fit", str(folder), "--model", "multiscale", "-o", str(tmp_path / "x.nmat"),
                                      "--steps", "1", "--set", "spatial_sise=16"])
    assert result.exit_code != 0 and "spatial_size" in result.output


def test_fit_neural_appearance_on_a_texture_set_folder(shared_data, tmp_path):
    """`neumat fit <texture-set folder> --model neural-appearance`: the two-phase training; the model reloads,
    evaluates and samples."""
    import torch

    from neumat import Query

    out = tmp_path / "wood_na.nmat"
    folder = shared_data / "svbrdf" / "Wood092_1K"
    args = ["fit", str(folder), "--model", "neural-appearance", "-o", str(out), "--steps", "4", "--quiet",
            "--source-option", "max_size=32", "--set", "batch_size=64"]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    model = load_model(out)
    assert model.name == "neural-appearance" and model.cfg.spatial_size == 32    # the texture's resolution
    q = Query(torch.tensor([[0.0, 0.6, 0.8]]), uv=torch.tensor([[0.2, 0.3]]))
    s = model.sample(q, torch.tensor([[0.3, 0.7]]))
    assert bool(s.pdf > 0) and torch.isfinite(model.eval(q.with_wo(s.wo))).all()
    bad = CliRunner().invoke(app, ["fit", str(folder), "--model", "neural-appearance", "-o", str(tmp_path / "x.nmat"),
                                   "--steps", "1", "--set", "spatial_sise=16"])
    assert bad.exit_code != 0 and "spatial_size" in bad.output


def test_fit_neural_appearance_on_a_layered_description(tmp_path):
    """A `.json` layered material is a source like any other: spatial_size comes from its coat maps, the encoder's
    surface_features from the material (5 per coat over a homogeneous base)."""
    import json

    spec = {"type": "layered", "base": "lambert:albedo=0.5/0.4/0.3", "samples": 4,
            "coats": [{"roughness": {"smudges": {"size": 16, "seed": 3}, "low": 0.05, "high": 0.3}}]}
    (tmp_path / "coated.json").write_text(json.dumps(spec))
    out = tmp_path / "coated.nmat"
    result = CliRunner().invoke(app, ["fit", str(tmp_path / "coated.json"), "--model", "neural-appearance", "-o",
                                      str(out), "--steps", "4", "--quiet", "--set", "batch_size=64", "--set",
                                      "queries=rusinkiewicz", "--set", "blur_degrees=5"])
    assert result.exit_code == 0, result.output
    model = load_model(out)
    assert model.cfg.spatial_size == 16 and model.cfg.surface_features == 5


def test_eval_scales_scores_a_texture_set_fit_across_texture_scales(shared_data, tmp_path):
    """`neumat fit` on a crop at a given origin, then `neumat eval --scales N` with the same source options: per-scale
    FLIP, its mean and the reference's noise floor, scale 0 at 1/8 texel per pixel; in a table too. A reference
    without textures is refused with a message naming what the scale series needs."""
    import json

    import pytest

    out = tmp_path / "wood.nmat"
    folder = str(shared_data / "svbrdf" / "Wood092_1K")
    crop = ["--source-option", "crop=16", "--source-option", "crop_origin=300,500"]
    fit = CliRunner().invoke(app, ["fit", folder, "--model", "tripleplane", "-o", str(out), "--steps", "2", "--quiet",
                                   "--set", "batch_size=64", *crop, "--source-option", "samples=2"])
    assert fit.exit_code == 0, fit.output
    assert load_model(out).cfg.spatial_size == 16
    args = ["eval", str(out), "--against", folder, *crop, "--source-option", "samples=4", "--resolution", "8",
            "--no-image", "--n-configs", "256", "--device", "cpu"]
    res = CliRunner().invoke(app, [*args, "--scales", "2", "--json"])
    assert res.exit_code == 0, res.output
    row = json.loads(res.stdout)
    s = row["scales"]
    assert len(s["flip"]) == len(s["floor"]) == 2 and s["texels_per_pixel"] == pytest.approx([1 / 8, 32])
    assert row["flip_scales_mean"] == pytest.approx(sum(s["flip"]) / 2) == s["flip_mean"]
    assert row["flip_scales_floor"] == s["floor_mean"] > 0
    table = CliRunner().invoke(app, [*args, "--scales", "1"])
    assert table.exit_code == 0 and "FLIP per texture scale" in table.output, table.output
    bad = CliRunner().invoke(app, ["eval", str(out), "--against", "lambert:albedo=0.5", "--scales", "2",
                                   "--resolution", "8", "--no-image", "--n-configs", "256"])
    assert bad.exit_code != 0 and "textured reference" in bad.output


def test_fit_without_a_model_picks_the_sources_default(tmp_path):
    """No --model: a texture-set folder fits the gated model, or tripleplane when it is a flat, rough dielectric,
    or NeuMIP when it is large and not (and says why), a BRDF spec NeuBRDF, a BTF SparseBTF, observations NeuPreSS,
    several sources the shared NeuBRDF; a missing file is one error line."""
    import pytest
    import torch

    from neumat.cli.fitting import default_model
    from neumat.core.errors import InputError
    from neumat.io.texture_set import TextureSet, write_texture_set
    from neumat.methods.latent_mlp.regime import LARGE_SOURCE_TEXELS

    folder = tmp_path / "foil"
    assert CliRunner().invoke(app, ["data", "texture-set", "foil", "-o", str(folder), "--size", "16"]).exit_code == 0
    out = tmp_path / "foil.nmat"
    result = CliRunner().invoke(app, ["fit", str(folder), "-o", str(out), "--steps", "2", "--set", "batch_size=64"])
    assert result.exit_code == 0, result.output
    assert "model multiscale: the default for this source: normal detail, metal or a near-mirror" in result.output
    assert load_model(out).name == "multiscale"
    # a flat, rough dielectric: normals tilted 2 degrees, roughness 0.5, metalness 0; tilted 4 degrees, a metal (mean
    # metalness 0.5 or more), or a near-mirror, is not
    h = w = 16
    def texture_set(tilt_deg, metalness, roughness=0.5):
        t = torch.deg2rad(torch.tensor(float(tilt_deg)))
        normal = torch.stack([torch.sin(t), torch.zeros(()), torch.cos(t)]).expand(h, w, 3).clone()
        return TextureSet(color=torch.rand(h, w, 3, generator=torch.Generator().manual_seed(0)), normal=normal,
                          roughness=torch.full((h, w), roughness), metalness=torch.full((h, w), float(metalness)),
                          height=torch.zeros(h, w), name="flat")
    for tilt, metal, rough, expected in ((2, 0, 0.5, "tripleplane"), (2, 0.4, 0.5, "tripleplane"),
                                         (2, 0.6, 0.5, "multiscale"), (2, 1, 0.5, "multiscale"),
                                         (2, 0, 0.1, "multiscale"), (4, 0, 0.5, "multiscale")):
        write_texture_set(texture_set(tilt, metal, rough), tmp_path / f"flat{tilt}{metal}{rough}")
        name, why = default_model([str(tmp_path / f"flat{tilt}{metal}{rough}")])
        said = re.search(r"mean normal tilt ([0-9.]+) deg, roughness ([0-9.]+), metalness ([0-9.]+)", why)
        assert name == expected and abs(float(said[1]) - tilt) < 0.3 and abs(float(said[2]) - rough) < 0.01, why
        assert abs(float(said[3]) - metal) < 0.01, why
    flat = tmp_path / "flat200.5"
    result = CliRunner().invoke(app, ["fit", str(flat), "-o", str(tmp_path / "flat.nmat"), "--steps", "2", "--set",
                                      "batch_size=64"])
    assert result.exit_code == 0, result.output
    assert "model tripleplane: the default for this source: a flat, rough dielectric" in result.output
    assert load_model(tmp_path / "flat.nmat").name == "tripleplane"
    # the rule was measured at the recommended preset on a CPU: elsewhere the paper's gated model
    assert default_model([str(flat)], preset="paper")[0] == "multiscale"
    assert default_model([str(flat)], device_type="cuda")[0] == "multiscale"
    # the crop decides: the flat left half of a set whose right half is tilted 20 degrees
    half = texture_set(0, 0)
    half.normal[:, w // 2:] = texture_set(20, 0).normal[:, w // 2:]
    write_texture_set(half, tmp_path / "half")
    assert default_model([str(tmp_path / "half")])[0] == "multiscale"
    assert default_model([str(tmp_path / "half")], {"crop": 8, "crop_origin": (0, 0)})[0] == "tripleplane"
    # the size decides past regime.LARGE_SOURCE_TEXELS (2 x 256^2): a tilted 256^2 set or a 362^2 metal gets the
    # gated model, the same on 363 x 362 texels and on 512^2 NeuMIP (and says so); a flat, rough dielectric
    # tripleplane at any size
    assert LARGE_SOURCE_TEXELS == 2 * 256 * 256 and 362 * 362 <= LARGE_SOURCE_TEXELS < 363 * 362
    for (h, w), tilt, metal, expected in (((256, 256), 20, 0, "multiscale"), ((362, 362), 2, 1, "multiscale"),
                                          ((363, 362), 20, 0, "neumip"), ((363, 362), 2, 1, "neumip"),
                                          ((512, 512), 20, 0, "neumip"), ((363, 362), 2, 0, "tripleplane")):
        folder = tmp_path / f"large{h}{tilt}{metal}"
        write_texture_set(texture_set(tilt, metal), folder)
        name, why = default_model([str(folder)])
        assert name == expected and f"{h} x {w} texels" in why, (h, tilt, metal, why)
        assert ("a large source" in why) == (expected == "neumip"), why
    (tmp_path / "a.nbtf").write_bytes(b"")
    assert default_model(["ggx:roughness=0.2"]) == ("neubrdf", "")
    assert default_model([str(tmp_path / "a.nbtf")]) == ("sparse-btf", "")
    assert default_model([str(tmp_path / "obs.npz")]) == ("neupress", "")
    assert default_model(["ggx:roughness=0.2", "ggx:roughness=0.4"]) == ("shared-neubrdf", "")
    with pytest.raises(InputError, match="does not exist"):
        default_model([str(tmp_path / "missing.binary")])


def test_fit_says_when_the_recipe_filters_targets_with_another_sample_count(shared_data, tmp_path):
    """The recommended CPU recipe trains on 32-position footprint targets (option target_samples): a fit given
    --source-option samples=2 says that it trains on 32 and how to train on 2; with that override it is silent."""
    folder = str(shared_data / "svbrdf" / "Wood092_1K")
    args = ["fit", folder, "--model", "tripleplane", "-o", str(tmp_path / "w.nmat"), "--steps", "1", "--device",
            "cpu", "--set", "batch_size=16", "--source-option", "crop=16", "--source-option", "samples=2"]
    said = CliRunner().invoke(app, args)
    assert said.exit_code == 0, said.output
    assert "filtered with 32 footprint positions" in said.output
    assert "--set option.target_samples=2" in said.output
    silent = CliRunner().invoke(app, [*args, "--set", "option.target_samples=2"])
    assert silent.exit_code == 0 and "footprint positions" not in silent.output, silent.output
