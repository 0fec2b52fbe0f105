from typer.testing import CliRunner

from neumat.cli.main import app
from neumat.io.modelfile import load_model


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


def test_fit_rejects_unknown_model_option(shared_data, tmp_path):
    folder = shared_data / "svbrdf" / "Wood092_1K"
    result = CliRunner().invoke(app, ["fit", str(folder), "--model", "multiscale", "-o", str(tmp_path / "x.nmat"),
                                      "--steps", "1", "--set", "spatial_sise=16"])
    assert result.exit_code != 0 and "spatial_size" in result.output
