"""The NBRDF authors' published networks (shared/data/merl/nbrdf_fits): reader, model, MERL conversion.

The reference is written here from the files with h5py, json and numpy in float64, independently of
neumat.io.nbrdf_keras and neumat.core.coords: x = (sin th, 0, cos th, sin td cos pd, sin td sin pd, cos td),
f = max(exp(W3 relu(W2 relu(W1 x + b1) + b2) + b3) - 1, 0) (asztr/Neural-BRDF, mitsuba/bsdfs/nn.h `Net::forward`).
"""
from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from neumat.core.errors import DataFormatError
from neumat.core.query import Query

MATERIALS = ("chrome", "gold-paint", "white-paint")


@pytest.fixture
def fits(shared_data):
    path = shared_data / "merl" / "nbrdf_fits"
    if not (path / "chrome.h5").is_file():
        pytest.skip(f"{path} has no NBRDF networks")
    pytest.importorskip("h5py")
    return path


def reference(path, name):
    """float64 numpy function (theta_h, theta_d, phi_d) -> (N, 3) from NAME.json + NAME.h5."""
    import h5py

    arch = json.loads((path / f"{name}.json").read_text())
    dense = [layer["config"] for layer in arch["config"]["layers"] if layer["class_name"] == "Dense"]
    assert [c["activation"] for c in dense] == ["relu", "relu", "linear"]
    with h5py.File(path / f"{name}.h5", "r") as f:
        ws = [(np.array(f[c["name"]][c["name"]]["kernel:0"], np.float64),
               np.array(f[c["name"]][c["name"]]["bias:0"], np.float64)) for c in dense]

    def f(th, td, pd):
        x = np.stack([np.sin(th), np.zeros_like(th), np.cos(th),
                      np.sin(td) * np.cos(pd), np.sin(td) * np.sin(pd), np.cos(td)], -1)
        for k, (w, b) in enumerate(ws):
            x = x @ w + b
            x = np.maximum(x, 0) if k < len(ws) - 1 else np.maximum(np.exp(x) - 1, 0)
        return x
    return f


def directions(th, ph, td, pd):
    """(wi, wo) of Rusinkiewicz angles, numpy: wi = Rz(ph) Ry(th) d, wo the same of (-dx, -dy, dz)."""
    def rot(v):
        x, y, z = v
        x, z = np.cos(th) * x + np.sin(th) * z, -np.sin(th) * x + np.cos(th) * z
        x, y = np.cos(ph) * x - np.sin(ph) * y, np.sin(ph) * x + np.cos(ph) * y
        return np.stack([x, y, z], -1)
    d = np.stack([np.sin(td) * np.cos(pd), np.sin(td) * np.sin(pd), np.cos(td)])
    return rot(d), rot(d * np.array([-1.0, -1.0, 1.0])[:, None])


def random_configurations(n, seed):
    r = np.random.default_rng(seed)
    th, ph = r.uniform(0, np.pi / 2, n), r.uniform(-np.pi, np.pi, n)
    td, pd = r.uniform(0, np.pi / 2, n), r.uniform(0, 2 * np.pi, n)
    wi, wo = directions(th, ph, td, pd)
    keep = (wi[:, 2] > 1e-3) & (wo[:, 2] > 1e-3) & (np.abs(np.sin(pd)) > 1e-6)
    return th[keep], td[keep], pd[keep], wi[keep], wo[keep]


@pytest.mark.parametrize("name", MATERIALS)
def test_matches_the_authors_formula(fits, name):
    from neumat.methods.baselines.nbrdf import NBRDF, nbrdf_from_keras

    ref = reference(fits, name)
    th, td, pd, wi, wo = random_configurations(4000, seed=len(name))
    q = Query(torch.from_numpy(wi), torch.from_numpy(wo))
    raw = NBRDF.from_keras(fits / f"{name}.h5", fold_phi_d=False).eval(q).detach().numpy()
    want = ref(th, td, pd)
    assert want.max() > 0.1
    np.testing.assert_allclose(raw, want, rtol=1e-9, atol=1e-12)
    folded = nbrdf_from_keras(fits / f"{name}.h5").eval(q).detach().numpy()
    np.testing.assert_allclose(folded, ref(th, td, np.where(np.sin(pd) < 0, pd - np.pi, pd)), rtol=1e-9, atol=1e-12)
    below = Query(q.wi, q.wo * torch.tensor([1.0, 1.0, -1.0], dtype=torch.float64))
    assert (NBRDF.from_keras(fits / f"{name}.h5").eval(below) == 0).all()


@pytest.mark.parametrize("name", MATERIALS)
def test_reciprocity(fits, name):
    """Folded (default): reciprocal. Raw: the authors' networks are not (documented in methods/baselines/nbrdf.py)."""
    from neumat.methods.baselines.nbrdf import NBRDF
    from neumat.testing.reciprocity import reciprocity_check

    assert reciprocity_check(NBRDF.from_keras(fits / f"{name}.h5"), n=4096, rtol=1e-9, atol=1e-12,
                             dtype=torch.float64)
    raw = reciprocity_check(NBRDF.from_keras(fits / f"{name}.h5", fold_phi_d=False), n=4096)
    assert not raw and raw.max_rel > 1e-3


def test_reader_arrays_and_errors(fits, tmp_path):
    from neumat.io.nbrdf_keras import read_nbrdf_keras

    net = read_nbrdf_keras(fits / "chrome.h5")
    assert net.dims == (6, 21, 21, 3) and net.activations == ["relu", "relu", "linear"]
    assert net.output == "exp_minus_one" and net.keras_version == "2.2.4"
    assert [k.shape for k in net.kernels] == [(6, 21), (21, 21), (21, 3)] and net.biases[2].shape == (3,)

    raw = (fits / "chrome.h5").read_bytes()
    (tmp_path / "cut.h5").write_bytes(raw[: len(raw) // 2])
    (tmp_path / "cut.json").write_text((fits / "chrome.json").read_text())
    with pytest.raises(DataFormatError, match="cut.h5"):
        read_nbrdf_keras(tmp_path / "cut.h5")
    from neumat.catalog.open_material import open_material
    with pytest.raises(DataFormatError, match="cut.h5"):
        open_material(tmp_path / "cut.h5")

    (tmp_path / "wide.h5").write_bytes(raw)
    (tmp_path / "wide.json").write_text((fits / "chrome.json").read_text().replace('"units": 21', '"units": 22', 1))
    with pytest.raises(DataFormatError, match="expected"):
        read_nbrdf_keras(tmp_path / "wide.h5")
    (tmp_path / "alone.h5").write_bytes(raw)
    with pytest.raises(Exception, match="json"):
        read_nbrdf_keras(tmp_path / "alone.h5")


def test_convert_to_merl_and_open(fits, tmp_path):
    from neumat.cli.main import app
    from neumat.io.merl import MERL_SCALE, read_merl
    from neumat.catalog.open_material import open_material

    out = tmp_path / "chrome.binary"
    r = CliRunner().invoke(app, ["data", "convert", str(fits / "chrome.h5"), "-o", str(out)])
    assert r.exit_code == 0, r.output
    table = read_merl(out).table
    r_ = np.random.default_rng(1)
    i, j, k = r_.integers(0, 90, 3000), r_.integers(0, 90, 3000), r_.integers(0, 180, 3000)
    th, td, pd = ((i + 0.5) / 90) ** 2 * np.pi / 2, (j + 0.5) / 90 * np.pi / 2, (k + 0.5) / 180 * np.pi
    wi, wo = directions(th, np.zeros_like(th), td, pd)
    ok = (wi[:, 2] > 0) & (wo[:, 2] > 0)
    got = table[:, i, j, k].T * np.asarray(MERL_SCALE)
    np.testing.assert_allclose(got[ok], reference(fits, "chrome")(th, td, pd)[ok], rtol=1e-9, atol=1e-12)
    assert (table[:, i[~ok], j[~ok], k[~ok]] == -1).all()
    m = open_material(out)
    q = Query(torch.from_numpy(wi[ok][:100]), torch.from_numpy(wo[ok][:100]))
    assert torch.isfinite(m.eval(q)).all()
