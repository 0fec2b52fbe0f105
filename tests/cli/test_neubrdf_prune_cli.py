"""NeuBRDF on sparse measurements through `neumat fit` (paper Sec. 3.2.1): replayed RGL measurement directions
(`rgl_samples`), recipe option prune, the pruned model's storage, and `neumat eval --member` of a shared fit."""
from __future__ import annotations

import json
import math
import re

import pytest
import torch
import typer
from typer.testing import CliRunner

from neumat.catalog.modelfile import load_model, save_model
from neumat.catalog.open_material import open_material
from neumat.core.errors import InputError
from neumat.core.query import Query
from neumat.fit.measured_samples import rgl_samples
from neumat.methods.neubrdf.model import NeuBRDF
from neumat.nn import healpix as hpx

from cli_util import fitting_app, output_text

SMALL = ["--set", "nside=8", "--set", "index_bits=4", "--set", "hidden=8", "--set", "batch_size=256",
         "--steps", "4", "--device", "cpu", "--quiet"]


@pytest.fixture
def app() -> typer.Typer:
    return fitting_app()


@pytest.fixture
def rgl(shared_data) -> str:
    return str(shared_data / "rgl" / "paper_white_rgb.bsdf")


def test_rgl_samples_are_the_measured_nodes(rgl):
    m = open_material(rgl)
    s = rgl_samples(m, azimuths=1)
    theta = m.rgb.param_values[1].float()
    # one incident azimuth (phi_i = 0), the file's elevations but the grazing 90 degrees, 32 x 32 nodes each
    assert torch.allclose(s.wi[:, 1], torch.zeros(len(s)), atol=1e-6) and bool((s.wi[:, 0] >= 0).all())
    elevations = torch.unique(torch.round(torch.acos(s.wi[:, 2].clamp(-1, 1)) * 1e4) / 1e4)
    assert torch.allclose(elevations, theta[:-1], atol=2e-4)
    assert len(s) <= 7 * 32 * 32
    # the file's inverse warp takes each (wi, wo) back to its node (but on the x = 0 column, where all nodes
    # are the mirror direction)
    h = s.wi + s.wo
    params, u_m, _ = m._angles(s.wi, h / h.norm(dim=-1, keepdim=True))
    node = m.vndf.invert(u_m, params)[0] * 31
    regular = node[:, 0] > 0.5
    assert float((node[regular] - node[regular].round()).abs().max()) < 1e-3
    assert torch.equal(s.value, m.eval(Query(s.wi, s.wo)).float())
    # isotropic: rotated copies with the same values
    s4 = rgl_samples(m, azimuths=4)
    n = len(s)
    assert len(s4) == 4 * n and torch.equal(s4.value[n:2 * n], s.value)
    rot = torch.stack([-s.wi[:, 1], s.wi[:, 0], s.wi[:, 2]], -1)  # +90 degrees
    assert torch.allclose(s4.wi[n:2 * n], rot, atol=1e-6)


def test_rgl_samples_refuses_other_materials():
    with pytest.raises(InputError, match="RGL"):
        rgl_samples(open_material("ggx:roughness=0.3"))


def test_cli_fit_with_pruning(app, rgl, tmp_path):
    runner = CliRunner()
    # N_side 16, b 6: large enough that the slots pruning drops outweigh its 1-bit-per-pixel mask
    args = ["fit", rgl, *SMALL, "--preset", "paper", "--set", "nside=16", "--set", "index_bits=6",
            "--set", "queries=replay",
            "--set", "measured_azimuths=1"]
    res = runner.invoke(app, [*args, "--set", "prune=true", "-o", str(tmp_path / "pruned.nmat")])
    assert res.exit_code == 0, res.output
    res = runner.invoke(app, [*args, "-o", str(tmp_path / "full.nmat")])
    assert res.exit_code == 0, res.output
    pruned, full = load_model(tmp_path / "pruned.nmat"), load_model(tmp_path / "full.nmat")
    assert pruned.pruned and not full.pruned
    # pruned to the measured directions: the levels of their supervised pixels
    s = rgl_samples(open_material(rgl), azimuths=1)
    sup = hpx.supervised_pixels(16, hpx.hemisphere_direction(s.wi, False))
    assert torch.equal(pruned.level_i.long(), hpx.pruned_levels(16, sup))
    assert 1 <= int(sup.sum()) <= 7  # 7 incident directions (two may share a pixel)
    # storage: the paper's 2 n b + 16 k 2^b with n the slots some pixel reads, the MLP at fp16, and the
    # levels as the 1-bit mask of supervised pixels of both grids
    used = int(pruned.used_slots().sum())
    assert used < full.used_slots().numel()
    mlp = sum(p.numel() for p in pruned.mlp.parameters())
    bits = used * 6 + 16 * 16 * 2 ** 6 + 16 * mlp + 2 * 12 * 16 ** 2
    assert pruned.size_bytes() == math.ceil(bits / 8) < full.size_bytes()
    state = pruned.state_dict()
    assert "grid.packed_index" not in state and state["packed_used_index"].numel() == math.ceil(used * 6 / 8)
    # evaluates (finite, the same after another save and load) and reads no unused slot
    q = Query(s.wi[::13], s.wo[::13])
    f = pruned.eval(q)
    assert bool(torch.isfinite(f).all()) and float(f.detach().abs().max()) > 0
    again = load_model(save_model(pruned, tmp_path / "again.nmat"))
    assert torch.equal(again.eval(q), f)
    # the file is smaller too
    assert (tmp_path / "pruned.nmat").stat().st_size < (tmp_path / "full.nmat").stat().st_size


def test_cli_fit_pruned_on_replay_cells(app, rgl, tmp_path):
    """queries=replay_cells (draws balanced over direction cells) trains a pruned model on the measurements too."""
    res = CliRunner().invoke(app, ["fit", rgl, *SMALL, "--preset", "paper", "--set", "queries=replay_cells",
                                   "--set", "measured_azimuths=1", "--set", "prune=true", "-o",
                                   str(tmp_path / "cells.nmat")])
    assert res.exit_code == 0, res.output
    model = load_model(tmp_path / "cells.nmat")
    s = rgl_samples(open_material(rgl), azimuths=1)
    sup = hpx.supervised_pixels(8, hpx.hemisphere_direction(s.wi, False))
    assert model.pruned and torch.equal(model.level_i.long(), hpx.pruned_levels(8, sup))


def test_cli_fit_on_reciprocal_measurements(app, rgl, tmp_path):
    """measured_reciprocal=true trains on each measurement and its reciprocal (wi and wo exchanged): pruned, the
    incident grid keeps the pixels of the measured outgoing directions too."""
    res = CliRunner().invoke(app, ["fit", rgl, *SMALL, "--preset", "paper", "--set", "queries=replay",
                                   "--set", "measured_azimuths=1", "--set", "measured_reciprocal=true",
                                   "--set", "prune=true", "-o", str(tmp_path / "reciprocal.nmat")])
    assert res.exit_code == 0, res.output
    model = load_model(tmp_path / "reciprocal.nmat")
    s = rgl_samples(open_material(rgl), azimuths=1)
    one_way = hpx.supervised_pixels(8, hpx.hemisphere_direction(s.wi, False))
    both = hpx.supervised_pixels(8, hpx.hemisphere_direction(torch.cat([s.wi, s.wo]), False))
    assert int(both.sum()) > int(one_way.sum())
    assert model.pruned and torch.equal(model.level_i.long(), hpx.pruned_levels(8, both))


@pytest.mark.parametrize("source, sets, match", [
    ("rgl", ["prune=true"], "prune=true: needs queries=replay"),
    ("ggx:roughness=0.3", ["queries=replay"], "holds no measurement samples"),
    ("ggx:roughness=0.3", ["queries=replay", "prune=true"], "holds no measurement samples"),
    ("ggx:roughness=0.3", ["queries=replay_cells"], "queries=replay_cells: the source .* holds no measurement"),
    ("rgl", ["queries=replay", "prune=yes"], "option.prune: expected true/false"),
    ("rgl", ["queries=replay", "measured_azimuths=0"], "option.measured_azimuths: expected a value >= 1, got 0"),
])
def test_cli_pruning_bad_combinations(app, rgl, tmp_path, source, sets, match):
    src = rgl if source == "rgl" else source
    res = CliRunner().invoke(app, ["fit", src, *SMALL, "--preset", "paper", *[a for s in sets for a in ("--set", s)],
                                   "-o", str(tmp_path / "x.nmat")])
    assert res.exit_code != 0
    assert re.search(match, output_text(res)), res.output


def test_pruned_levels_of_other_origin_are_stored_as_levels(tmp_path):
    """Levels that are not those of their supervised pixels (set by hand) keep their packed form."""
    torch.manual_seed(0)
    model = NeuBRDF(nside=4, index_bits=3, hidden=8)
    model.level_i[5] = 2  # its level-1 ancestor holds supervised pixels: pruned_levels would say 1
    model._update_pruning()
    model.runtime()
    assert "packed_level_i" in model.state_dict() and "supervised_level_o" in model.state_dict()
    loaded = load_model(save_model(model, tmp_path / "m.nmat"))
    assert torch.equal(loaded.level_i, model.level_i)
    q = Query(*(torch.nn.functional.normalize(torch.rand(64, 3) + torch.tensor([0, 0, 0.2]), dim=-1)
                for _ in range(2)))
    assert torch.equal(loaded.eval(q), model.eval(q))


def test_eval_member_of_a_shared_fit(app, tmp_path):
    runner = CliRunner()
    specs = ["ggx:roughness=0.2", "ggx:roughness=0.5"]
    out = tmp_path / "shared.nmat"
    res = runner.invoke(app, ["fit", *specs, "--model", "shared-neubrdf", "--set", "nside=2", "--set", "index_bits=3",
                              "--set", "hidden=8", "--set", "batch_size=128", "--steps", "3", "--quiet",
                              "-o", str(out)])
    assert res.exit_code == 0, res.output  # num_materials follows the sources
    model = load_model(out)
    assert model.cfg.num_materials == 2
    rows = []
    for i in (0, 1):
        res = runner.invoke(app, ["eval", str(out), "--against", specs[1], "--member", str(i), "--no-image",
                                  "--json", "--n-configs", "512"])
        assert res.exit_code == 0, res.output
        rows.append(json.loads(res.stdout))
    assert rows[0]["rmse_hdr"] != rows[1]["rmse_hdr"]  # two different materials
    assert rows[1]["bytes_fp16"] == int(model.size_bytes_per_material())
    res = runner.invoke(app, ["eval", str(out), "--against", specs[0], "--member", "2", "--no-image"])
    assert res.exit_code != 0 and "expected an integer in [0, 2)" in output_text(res)


class Interrupt(Exception):
    pass


def test_pruned_fit_resumes_to_the_uninterrupted_one(tmp_path):
    """A fit with option prune interrupted after step 2 and resumed from its checkpoint ends as the
    uninterrupted fit (the recipe prunes again, deterministically; the checkpoint holds the levels)."""
    from dataclasses import replace

    from neumat.fit.measured_samples import MeasuredSamples
    from neumat.fit.method import recipe_for
    from neumat.fit.trainer import fit

    gen = torch.Generator().manual_seed(0)
    wi = torch.nn.functional.normalize(torch.rand(40, 3, generator=gen) * torch.tensor([0.3, 0.3, 1.0]), dim=-1)
    wo = torch.nn.functional.normalize(torch.rand(40, 3, generator=gen) + torch.tensor([0, 0, 0.5]), dim=-1)
    samples = MeasuredSamples.from_material(open_material("ggx:roughness=0.3"), Query(wi, wo))
    r = recipe_for("neubrdf")
    recipe = replace(r, steps=4, batch_size=64, log_every=1, checkpoint_every=1, lr_decay_every=2,
                     queries="replay", options={**r.options, "prune": True})

    def run(**kw):
        torch.manual_seed(0)
        model = NeuBRDF(nside=4, index_bits=3, hidden=8)
        return model, fit(model, samples, recipe, progress=False, device="cpu", **kw)

    ref_model, _ = run()
    assert ref_model.pruned
    ckpt = tmp_path / "fit.ckpt"

    def stop(record):
        if record["step"] == 2:
            raise Interrupt

    with pytest.raises(Interrupt):
        run(checkpoint=ckpt, callback=stop)
    model, _ = run(checkpoint=ckpt, resume=True)
    ref_state, state = ref_model.state_dict(), model.state_dict()
    assert ref_state.keys() == state.keys() and all(torch.equal(ref_state[k], state[k]) for k in ref_state)
