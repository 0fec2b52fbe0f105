"""`neumat fit-dictionary` warns when its training set is too small for K, and btf-generate's default size
splits into SparseBTF's patches."""
from __future__ import annotations

import pytest
import typer
from typer.testing import CliRunner

from btf_util import synthetic_btf
from neumat.cli import btf as btf_cli
from neumat.core.errors import InputError
from neumat.methods.sparse_btf.dictionary_train import (PAPER_POINTS_PER_DICTIONARY, train_dictionary,
                                                        training_size_warning)
from neumat.io.btf import write_btf
from neumat.methods.sparse_btf.model import Config


def test_rule_flags_the_issue_set_and_passes_the_papers():
    # the issue's set: three 50 x 50 BTFs at 17 x 17 directions, 10 x 10 patches: 75 points for K = 8
    msg = training_size_warning(75, 8, (32, 8, 8), (10, 10, 17, 17))
    assert msg is not None and "9 per dictionary" in msg and "paper's 360" in msg and "2880 points" in msg
    # the paper's: 2880 points for K = 8 at 151 x 151 directions, tau_l = (256, 32, 32)
    assert training_size_warning(2880, 8, (256, 32, 32), (10, 10, 151, 151)) is None
    assert training_size_warning(8 * PAPER_POINTS_PER_DICTIONARY - 1, 8, (32, 8, 8), (10, 10, 17, 17)) is not None
    # below the Procrustes floor: 151 / 32 -> 5 members per dictionary at least
    msg = training_size_warning(32, 8, (256, 32, 32), (10, 10, 151, 151))
    assert "floor of 5" in msg and "fewer dictionaries" not in msg
    assert "K <= 2" in training_size_warning(1000, 8, (32, 8, 8), (10, 10, 17, 17))


def test_train_dictionary_warns_and_names_sizes():
    btfs = [synthetic_btf(s) for s in (1, 2)]                 # 8 x 8 texels, 4 x 4 patches: 8 points
    with pytest.warns(UserWarning, match="8 training data points for K = 2 dictionaries is 4 per dictionary"):
        train_dictionary(btfs, num_dictionaries=2, tau_train=(16, 4, 4), patch=4, max_iters=1)
    with pytest.raises(InputError, match=r"8 x 8 texels, which do not split into the dictionary's 3 x 3 patches"):
        train_dictionary(btfs, num_dictionaries=2, tau_train=(16, 4, 4), patch=3, max_iters=1)


def test_cli_sizes_agree(tmp_path):
    app, data = typer.Typer(), typer.Typer()
    btf_cli.register(app)
    btf_cli.register_data(data)
    app.add_typer(data, name="data")
    default = typer.main.get_command(app).commands["data"].commands["btf-generate"].params
    size = next(p for p in default if p.name == "size").default
    assert size % Config.patch == 0
    r = CliRunner().invoke(app, ["data", "btf-generate", "procedural:bumps", "-o", str(tmp_path / "b.nbtf"),
                                 "--size", "8", "--directions", "5", "--spp", "1", "-q"])
    assert r.exit_code == 0, r.output
    assert f"8 texels do not split into SparseBTF's {Config.patch} x {Config.patch} patches" in r.output
    paths = [write_btf(tmp_path / f"b{i}.nbtf", synthetic_btf(i)) for i in (1, 2)]
    with pytest.warns(UserWarning, match="per dictionary"):
        r = CliRunner().invoke(app, ["fit-dictionary", *map(str, paths), "-o", str(tmp_path / "d.nmat"), "-k", "2",
                                     "--tau", "16,4,4", "--patch", "4", "--iterations", "1", "-q"])
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(app, ["fit-dictionary", *map(str, paths), "-o", str(tmp_path / "d.nmat"), "-q"])
    assert r.exit_code == 2 and "do not split into the dictionary's 10 x 10 patches" in " ".join(r.output.split())
