"""`neumat data btf-generate` and `neumat fit-dictionary`."""
from __future__ import annotations

import pytest
import typer
from typer.testing import CliRunner

from neumat.cli import btf as btf_cli
from neumat.io.btf import write_btf
from neumat.reflectance.btf import read_btf
from neumat.methods.sparse_btf.dictionary import BTFDictionary
from btf_util import synthetic_btf


def _apps():
    app, data = typer.Typer(), typer.Typer()
    btf_cli.register(app)
    btf_cli.register_data(data)
    app.add_typer(data, name="data")
    return app


def test_fit_dictionary_and_errors(tmp_path):
    paths = [write_btf(tmp_path / f"b{i}.nbtf", synthetic_btf(i)) for i in (1, 2)]
    out = tmp_path / "dict.nmat"
    r = CliRunner().invoke(_apps(), ["fit-dictionary", *map(str, paths), "-o", str(out), "-k", "2",
                                     "--tau", "16,4,4", "--patch", "4", "--iterations", "3"])
    assert r.exit_code == 0, r.output
    d = BTFDictionary.load(out)
    assert d.tau_train == (16, 4, 4) and d.num_dictionaries == 2
    r = CliRunner().invoke(_apps(), ["fit-dictionary", str(paths[0]), "-o", str(out), "--tau", "1,2"])
    assert r.exit_code == 2 and "tau" in r.output


def test_btf_generate(tmp_path, shared_data):
    out = tmp_path / "wood.nbtf"
    r = CliRunner().invoke(_apps(), ["data", "btf-generate", str(shared_data / "svbrdf" / "Wood092_1K"), "-o", str(out),
                                     "--size", "8", "--crop", "64", "--directions", "5", "--spp", "1"])
    assert r.exit_code == 0, r.output
    btf = read_btf(out)
    assert btf.data.shape == (5, 5, 8, 8, 3) and float(btf.data.max()) > 0


def test_btf_generate_procedural_material(tmp_path):
    """`procedural:<class>~<variant>` generates the same BTF as the library call; an unknown class is refused."""
    import torch

    from neumat.reflectance.btf import direction_set
    from neumat.reflectance.btf_generate import generate_btf
    from neumat.reflectance.procedural_texture import procedural_texture_set

    out = tmp_path / "bricks.nbtf"
    r = CliRunner().invoke(_apps(), ["data", "btf-generate", "procedural:bricks~2", "-o", str(out), "--size", "8",
                                     "--directions", "5", "--spp", "1"])
    assert r.exit_code == 0, r.output
    d = direction_set(5)
    expected = generate_btf(procedural_texture_set("bricks", 8, seed=1, variant=2), d, d, relief=4.0, spp=1)
    torch.testing.assert_close(read_btf(out).data.float(), expected.data, rtol=2e-3, atol=1e-4)   # stored fp16
    r = CliRunner().invoke(_apps(), ["data", "btf-generate", "procedural:velvet", "-o", str(tmp_path / "v.nbtf")])
    assert r.exit_code != 0 and "procedural material 'velvet'" in r.output
    r = CliRunner().invoke(_apps(), ["data", "btf-generate", "procedural:bricks~2", "-o", str(tmp_path / "n.nbtf"),
                                     "--size", "8", "--directions", "rings:3xnan"])
    assert r.exit_code == 2 and r.output.startswith("error: ") and "ring step" in r.output, r.output
    assert not (tmp_path / "n.nbtf").exists()


def test_btf_generate_noise_is_the_library_noise(tmp_path):
    """`--noise` adds `generate_btf(..., noise=...)`'s seeded sensor noise."""
    import torch

    from neumat.reflectance.btf import direction_set
    from neumat.reflectance.btf_generate import generate_btf
    from neumat.reflectance.procedural_texture import procedural_texture_set

    out = tmp_path / "bumps.nbtf"
    r = CliRunner().invoke(_apps(), ["data", "btf-generate", "procedural:bumps", "-o", str(out), "--size", "8",
                                     "--directions", "5", "--spp", "1", "--noise", "0.1", "-q"])
    assert r.exit_code == 0, r.output
    d = direction_set(5)
    clean = generate_btf(procedural_texture_set("bumps", 8, seed=1), d, d, relief=4.0, spp=1)
    expected = generate_btf(procedural_texture_set("bumps", 8, seed=1), d, d, relief=4.0, spp=1, noise=0.1)
    torch.testing.assert_close(read_btf(out).data.float(), expected.data, rtol=2e-3, atol=1e-4)   # stored fp16
    assert float((read_btf(out).data.float() - clean.data).abs().max()) > 1e-2


def test_btf_generate_interreflection_and_fibres_are_the_library_options(tmp_path):
    """`--interreflection` and `--fibres` / `--fibre-direction` pass through to `generate_btf`."""
    import torch

    from neumat.reflectance.btf import direction_set
    from neumat.reflectance.btf_generate import generate_btf
    from neumat.reflectance.procedural_texture import procedural_texture_set

    out = tmp_path / "weave.nbtf"
    r = CliRunner().invoke(_apps(), ["data", "btf-generate", "procedural:weave", "-o", str(out), "--size", "8",
                                     "--directions", "5", "--spp", "1", "--interreflection", "4", "--fibres", "0.7",
                                     "--fibre-direction", "weave:2", "-q"])
    assert r.exit_code == 0, r.output
    d = direction_set(5)
    ts = procedural_texture_set("weave", 8, seed=1)
    expected = generate_btf(ts, d, d, relief=4.0, spp=1, interreflection=4, fibres=0.7, fibre_direction="weave:2")
    plain = generate_btf(ts, d, d, relief=4.0, spp=1)
    torch.testing.assert_close(read_btf(out).data.float(), expected.data, rtol=2e-3, atol=1e-4)   # stored fp16
    assert float((expected.data - plain.data).abs().max()) > 1e-2
    r = CliRunner().invoke(_apps(), ["data", "btf-generate", "procedural:weave", "-o", str(out), "--size", "8",
                                     "--directions", "5", "--spp", "1", "--interreflection", "3", "-q"])
    assert r.exit_code != 0 and "square number" in r.output


def test_fit_sparse_btf_with_a_dictionary(tmp_path):
    """`neumat fit BTF --model sparse-btf --set dictionary=D --set tau=T`: codes the BTF; the saved model loads and
    evaluates like the coded one."""
    import torch

    from neumat import Query, load
    from neumat.cli.main import app

    paths = [write_btf(tmp_path / f"b{i}.nbtf", synthetic_btf(i)) for i in (1, 2, 3)]
    dictionary = tmp_path / "dict.nmat"
    r = CliRunner().invoke(app, ["fit-dictionary", *map(str, paths[:2]), "-o", str(dictionary), "-k", "2",
                                 "--tau", "16,4,4", "--patch", "4", "--iterations", "3"])
    assert r.exit_code == 0, r.output
    out = tmp_path / "coded.nmat"
    r = CliRunner().invoke(app, ["fit", str(paths[2]), "--model", "sparse-btf", "--set",
                                 f"dictionary={dictionary}", "--set", "tau=32,8,8", "-o", str(out)])
    assert r.exit_code == 0, r.output
    model = load(out)
    assert model.cfg.tau == (32, 8, 8)
    btf = read_btf(paths[2])
    q = Query(btf.light_dirs[:4], btf.view_dirs[:4], uv=torch.full((4, 2), 0.3))
    assert torch.isfinite(model.eval(q)).all() and (model.eval(q) > 0).all()
    # without a dictionary the fit's first phase trains one on the BTF itself (and says that measures nothing
    # about generalisation); the patch must then split the BTF's texels
    r = CliRunner().invoke(app, ["fit", str(paths[2]), "--model", "sparse-btf", "-o", str(out)])
    assert r.exit_code == 2 and "patches" in r.output
    with pytest.warns(UserWarning, match="trained on the BTF it then codes"):
        r = CliRunner().invoke(app, ["fit", str(paths[2]), "--model", "sparse-btf", "--set", "patch=4", "--set",
                                     "num_dictionaries=2", "--set", "tau_train=16,4,4", "--set", "tau=16,4,4",
                                     "--steps", "3", "-q", "-o", str(out)])
    assert r.exit_code == 0, r.output
    assert load(out).cfg.patch == 4
