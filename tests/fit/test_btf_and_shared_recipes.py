"""SparseBTF (dictionary then coding), PCA-BTF (one-step solve) and shared-codebook NeuBRDF (a list of sources)
through the one trainer: results equal the direct calls, and a fit interrupted by a checkpoint mid-phase
resumes bit for bit."""
from __future__ import annotations

import warnings
from dataclasses import replace

import pytest
import torch

from neumat.core.errors import InputError
from neumat.methods.sparse_btf.pca_solve import fit_pca
from neumat.fit.method import recipe_for
from neumat.methods.sparse_btf.dictionary_train import train_dictionary
from neumat.fit.trainer import fit
from neumat.methods.sparse_btf.pca import PCABTF
from neumat.methods.neubrdf.shared_model import SharedNeuBRDF
from neumat.methods.sparse_btf.model import SparseBTF
from neumat.methods.sparse_btf.dictionary import rgb_to_model_space
from neumat.reflectance.analytic import GGX, Plastic

from btf_util import synthetic_btf

PATCH = 4
SPARSE = dict(patch=PATCH, num_dictionaries=2, tau=(24, 8, 8), tau_train=(24, 8, 8))


class Interrupt(Exception):
    pass


def _stop_at(step: int):
    def callback(record):
        if record["step"] == step:
            raise Interrupt
    return callback


def _strip(history):
    return [{k: v for k, v in r.items() if k != "seconds"} for r in history]


def _assert_same(a: torch.nn.Module, b: torch.nn.Module) -> None:
    sa, sb = a.state_dict(), b.state_dict()
    assert sa.keys() == sb.keys()
    for k in sa:
        assert torch.equal(sa[k], sb[k]), k


def _interrupted_then_resumed(make, source, ckpt, stop: int, **kw):
    """Fit make() with a checkpoint, interrupted after step `stop`; then resume a fresh make() from it."""
    with pytest.raises(Interrupt):
        fit(make(), source, checkpoint=ckpt, callback=_stop_at(stop), progress=False, **kw)
    assert torch.load(ckpt, weights_only=True)["step"] == stop
    model = make()
    return model, fit(model, source, checkpoint=ckpt, resume=True, progress=False, **kw)


def test_sparse_btf_dictionary_then_coding_resumes_bit_for_bit(tmp_path):
    btf = synthetic_btf(1)
    make = lambda: SparseBTF.for_btf(btf, **SPARSE)  # noqa: E731
    with pytest.warns(UserWarning, match="does not measure"):
        ref = fit(make(), btf, steps=5, progress=False)                 # 4 dictionary iterations + coding
    assert [r["phase"] for r in ref.history] == ["dictionary"] * 4 + ["coding"] and ref.steps == 5
    ys = [r["Y"] for r in ref.history[:4]]
    assert all(b <= a * (1 + 1e-6) for a, b in zip(ys, ys[1:]))       # the objective never rises
    for c in range(3):
        assert ref.model.ensemble(c).orthonormality_error() < 1e-5
    with pytest.warns(UserWarning):
        model, res = _interrupted_then_resumed(make, btf, tmp_path / "fit.ckpt", stop=2, steps=5)
    _assert_same(ref.model, model)
    assert _strip(res.history) == _strip(ref.history)
    # the coded model answers queries like the one encode builds from the same ensembles
    decoded = ref.model.decode()
    assert float(((decoded.data - btf.data) ** 2).mean()) < float((btf.data ** 2).mean())


def test_sparse_btf_with_a_given_dictionary_equals_encode(tmp_path):
    dictionary = train_dictionary([synthetic_btf(s) for s in (1, 2, 3)], num_dictionaries=2, tau_train=(24, 8, 8),
                                  patch=PATCH, max_iters=3, seed=0)
    path = dictionary.save(tmp_path / "dict.nmat")
    btf = synthetic_btf(7)
    recipe = recipe_for("sparse-btf")
    recipe.options["dictionary"] = str(path)
    with warnings.catch_warnings():
        warnings.simplefilter("error")                                 # no warning: the dictionary is not the BTF's
        res = fit(SparseBTF.for_btf(btf, **SPARSE), btf, recipe, progress=False)
    assert res.steps == 1 and [r["phase"] for r in res.history] == ["coding"]
    _assert_same(res.model, SparseBTF.encode(btf, dictionary.__class__.load(path)))
    with pytest.raises(InputError, match="patch, K, tau_train"):
        fit(SparseBTF.for_btf(btf, **{**SPARSE, "num_dictionaries": 3}), btf, recipe, progress=False)
    with pytest.raises(InputError, match="ONE BTF"):
        fit(SparseBTF.for_btf(btf, **SPARSE), [btf, btf], recipe, progress=False)
    with pytest.raises(InputError, match="built for"):
        fit(SparseBTF.for_btf(synthetic_btf(1, size=12), **SPARSE), btf, recipe, progress=False)


def test_pca_btf_through_fit_equals_the_direct_solve():
    btf = synthetic_btf(3)
    for ranks in ((4, 2, 2), (1, 0, 3)):
        res = fit(PCABTF.for_btf(btf, ranks=ranks), btf, progress=False)
        ref = fit_pca(btf, ranks)
        _assert_same(res.model, ref)
        assert res.steps == 1 and res.history[0]["phase"] == "solve"
        # the logged error is the model-space error of the truncation
        err = float(((rgb_to_model_space(ref.decode().data, 0.01) - rgb_to_model_space(btf.data, 0.01)) ** 2).mean())
        assert res.history[0]["mse"] == pytest.approx(err, rel=1e-3, abs=1e-9)
    with pytest.raises(InputError, match="built for"):
        fit(PCABTF(ranks=(1, 1, 1)), btf, progress=False)


SMALL = dict(nside=4, index_bits=5, hidden=16)


def test_shared_neubrdf_list_of_sources_resumes_bit_for_bit(tmp_path):
    sources = [Plastic(diffuse=(0.6, 0.3, 0.15), roughness=0.3), GGX(roughness=0.2)]
    recipe = replace(recipe_for("shared-neubrdf"), batch_size=256, ema=0.05, lr_decay_every=3, log_every=2,
                     checkpoint_every=2)

    def make():
        torch.manual_seed(0)
        return SharedNeuBRDF(num_materials=2, **SMALL)

    ref = fit(make(), sources, recipe, steps=8, progress=False)
    model, res = _interrupted_then_resumed(make, sources, tmp_path / "fit.ckpt", stop=4, recipe=recipe, steps=8)
    _assert_same(ref.model, model)
    assert _strip(res.history) == _strip(ref.history) and len(res.history) == 4
    with pytest.raises(InputError, match="2 materials"):
        fit(make(), sources[:1], recipe, steps=1, progress=False)
    with pytest.raises(InputError, match="list of Materials"):
        fit(make(), sources[0], recipe, steps=1, progress=False)


@pytest.mark.parametrize("stop", [1, 2, 3, 5])
def test_shared_neubrdf_cpu_path_resumes_bit_for_bit_in_every_phase(stop, tmp_path):
    """The CPU recipe's path for the joint fit (coarse grid, dense warm-up, joint k-means into the shared codebook,
    VQ with candidates): phases in that order, a VQ model with candidates at the end, and a checkpoint inside the
    coarse (1), at the switch to the model's grid (2), at the quantisation (3) and inside the VQ phase (5)
    resumes to the uninterrupted fit."""
    from neumat.fit.method import recipe_config_for_source

    sources = [Plastic(diffuse=(0.6, 0.3, 0.15), roughness=0.3), GGX(roughness=0.2)]
    cpu = recipe_for("shared-neubrdf", "cpu")
    assert {k: cpu.options[k] for k in ("coarse_fraction", "dense_warmup", "vq_candidates")} == \
        {"coarse_fraction": 0.4, "dense_warmup": 0.7, "vq_candidates": 8}
    recipe = replace(cpu, steps=6, batch_size=256, ema=0.05, log_every=1, checkpoint_every=1,
                     options={**cpu.options, "coarse_fraction": 0.3, "dense_warmup": 0.5, "vq_candidates": 2,
                              "coarse_nside": 2})
    derived = recipe_config_for_source("shared-neubrdf", sources, recipe.options)
    assert derived == {"num_materials": 2}  # the presets set features; the dense warm-up needs them dense
    derived["features"] = "dense"

    def make():
        torch.manual_seed(0)
        return SharedNeuBRDF(**{**derived, **SMALL})

    phases = []
    ref = fit(make(), sources, recipe, progress=False, callback=lambda r: phases.append(r["phase"]))
    assert phases == ["coarse"] * 2 + ["dense"] + ["vq"] * 3
    assert ref.model.cfg.features == "vq" and ref.model.cfg.nside == SMALL["nside"]
    assert ref.model.grid.candidates.shape == (ref.model.grid_rows(SMALL["nside"]), 2)
    model, res = _interrupted_then_resumed(make, sources, tmp_path / "fit.ckpt", stop=stop, recipe=recipe)
    _assert_same(ref.model, model)
    assert _strip(res.history) == _strip(ref.history)
    assert recipe_config_for_source("shared-neubrdf", sources, recipe_for("shared-neubrdf").options) == \
        {"num_materials": 2}  # the paper's recipe: end-to-end VQ
