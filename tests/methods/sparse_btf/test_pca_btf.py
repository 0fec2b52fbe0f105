"""PCA baseline of BTFs (equal-storage comparison partner of SparseBTF)."""
from __future__ import annotations

from dataclasses import replace

import pytest
import torch

from neumat import InputError, Query
from neumat.methods.sparse_btf.pca_solve import best_ranks, decompose, fit_pca
from neumat.catalog.modelfile import load_model, save_model
from neumat.fit.method import recipe_for
from neumat.fit.trainer import fit
from neumat.methods.sparse_btf.pca import PCABTF, rank_budget
from neumat.methods.sparse_btf.model import Config as SparseConfig, storage_bytes
from neumat.methods.sparse_btf.dictionary import rgb_to_model_space
from neumat.methods.sparse_btf.model import mse
from neumat.nn import cpu_kernels
from neumat.reflectance.btf import TabulatedBTF

from btf_util import N_DIRS, SIZE, assert_kernel_equals_torch, non_reciprocal_btf, synthetic_btf


def test_full_rank_is_exact_and_error_falls_with_rank():
    btf = synthetic_btf(3)
    full = fit_pca(btf, (N_DIRS ** 2,) * 3)
    assert mse(btf, full.decode()) < 1e-9
    errs = [mse(btf, fit_pca(btf, (r, r, r)).decode()) for r in (1, 2, 4, 8, 16)]
    assert all(b < a for a, b in zip(errs[:4], errs[1:4]))
    assert errs[3] < 1e-12 and errs[4] <= errs[3]             # the synthetic BTF has rank 7 in log-YUV


def test_eval_at_bins_and_texel_centres_matches_decoded_table(gen):
    model = fit_pca(synthetic_btf(4), (4, 2, 2))
    table = model.decode().data
    n = 40
    li, vi = torch.randint(0, N_DIRS, (2, n), generator=gen)
    rows, cols = torch.randint(0, SIZE, (2, n), generator=gen)
    uv = torch.stack([(cols + 0.5) / SIZE, 1 - (rows + 0.5) / SIZE], -1)
    q = Query(model.light_dirs[li], model.view_dirs[vi], uv=uv)
    assert torch.allclose(model.eval(q), table[li, vi, rows, cols], rtol=1e-4, atol=1e-5)


def test_rank_budget_fits_the_budget():
    budget = 20000
    total = rank_budget(budget, N_DIRS, N_DIRS, SIZE, SIZE)
    ranks = best_ranks(decompose(synthetic_btf(5)).eigenvalues, total)
    used = fit_pca(synthetic_btf(5), ranks).storage()["total"]
    assert sum(ranks) == total > 0
    assert used <= budget < used + 2 * (N_DIRS ** 2 + SIZE ** 2)
    with pytest.raises(InputError, match="budget"):
        rank_budget(10, N_DIRS, N_DIRS, SIZE, SIZE)


def test_best_ranks_is_the_best_split_by_brute_force():
    btf = synthetic_btf(6)
    ref = rgb_to_model_space(btf.data, 0.01)

    def model_space_error(ranks):
        return float(((rgb_to_model_space(fit_pca(btf, ranks).decode().data, 0.01) - ref) ** 2).sum())

    for total in (1, 3, 7):
        splits = [(a, b, total - a - b) for a in range(total + 1) for b in range(total + 1 - a)]
        errors = {s: model_space_error(s) for s in splits}
        best = best_ranks(decompose(btf).eigenvalues, total)
        assert sum(best) == total
        assert errors[best] <= min(errors.values()) * (1 + 1e-6) + 1e-9
        assert len(set(errors.values())) > 1                   # the split matters on this BTF
    with pytest.raises(InputError, match="non-negative"):
        best_ranks(decompose(btf).eigenvalues, -1)


def test_both_gram_sides_and_the_randomised_path_give_the_same_components():
    btf = synthetic_btf(7, size=16)                          # 256 texels > 81 angular samples: angle Gram
    small = TabulatedBTF(btf.data[:, :, :4, :6], btf.light_dirs, btf.view_dirs)   # 24 texels: texel Gram
    angle_side, texel_side = decompose(btf), decompose(small)
    randomised = decompose(btf, max_rank=20, exact_limit=0, oversample=4)
    torch.rand(3)                                         # the global generator state must not matter
    again = decompose(btf, max_rank=20, exact_limit=0, oversample=4)
    assert all(torch.equal(a, b) for a, b in zip(randomised.eigenvalues, again.eigenvalues))
    assert torch.equal(randomised.basis, again.basis)
    assert angle_side.exact and texel_side.exact and not randomised.exact
    r = 6
    for dec, b in ((angle_side, btf), (texel_side, small), (randomised, btf)):
        model = fit_pca(b, (r, r, r), decomposition=dec)
        yuv = rgb_to_model_space(b.data, 0.01)
        err = float(((rgb_to_model_space(model.decode().data, 0.01) - yuv) ** 2).sum())
        tail = sum(float(e[r:].sum()) for e in decompose(b).eigenvalues)   # the Eckart-Young optimum
        assert err == pytest.approx(tail, rel=1e-4)
    for e, f in zip(angle_side.eigenvalues, randomised.eigenvalues):
        assert torch.allclose(e[:20], f, rtol=1e-4, atol=1e-7 * float(e[0]))


def test_fit_refuses_a_decomposition_of_another_btf_or_too_few_components():
    btf = synthetic_btf(8)
    with pytest.raises(InputError, match="another BTF"):
        fit_pca(btf, (2, 1, 1), decomposition=decompose(synthetic_btf(8), log_eps=0.1))
    with pytest.raises(InputError, match="exceed"):
        fit_pca(btf, (4, 1, 1), decomposition=decompose(btf, max_rank=3))


def test_without_ranks_it_takes_sparse_btfs_per_btf_bytes(tmp_path):
    """The default model (no ranks): the most components within a SparseBTF's per-BTF bytes for the same BTF (the
    paper's comparison at equal storage), split by least error; the same through the trainer's recipe, whose
    budget_bytes option sets another budget; the chosen ranks travel with the saved model."""
    btf = synthetic_btf(9, size=10)
    model = fit_pca(btf)
    sparse = storage_bytes(SparseConfig(n_light=N_DIRS, n_view=N_DIRS, height=10, width=10))["per_btf"]
    one = 2 * (N_DIRS ** 2 + 10 ** 2)                     # a component's basis and coefficients at fp16
    used = model.storage()["total"]
    assert used <= sparse < used + one
    assert model.cfg.ranks == best_ranks(decompose(btf).eigenvalues, sum(model.cfg.ranks))
    assert model.cfg.ranks[0] > 0 and sum(model.cfg.ranks) > max(model.cfg.ranks)
    solved = fit(PCABTF.for_btf(btf), btf, progress=False).model
    assert solved.cfg.ranks == model.cfg.ranks
    assert torch.equal(solved.basis, model.basis) and torch.equal(solved.coeffs, model.coeffs)
    recipe = recipe_for("pca-btf")
    small = fit(PCABTF.for_btf(btf), btf, replace(recipe, options={**recipe.options, "budget_bytes": 2000}),
                progress=False).model
    assert small.storage()["total"] <= 2000 < small.storage()["total"] + one
    assert fit_pca(btf, budget_bytes=2000).cfg.ranks == small.cfg.ranks
    save_model(model, tmp_path / "pca.nmat")
    loaded = load_model(tmp_path / "pca.nmat")
    assert loaded.cfg.ranks == model.cfg.ranks and torch.equal(loaded.decode().data, model.decode().data)


def test_a_budget_it_cannot_meet_is_refused():
    with pytest.raises(InputError, match="no SparseBTF size"):
        fit_pca(synthetic_btf(9))                         # 8 x 8 texels: not a multiple of SparseBTF's patch
    with pytest.raises(InputError, match="does not even hold"):
        fit_pca(synthetic_btf(9), budget_bytes=100)
    with pytest.raises(InputError, match="three non-negative integers"):
        PCABTF.for_btf(synthetic_btf(9), ranks=(2, 1))
    with pytest.raises(InputError, match="no ranks yet"):
        PCABTF.for_btf(synthetic_btf(9)).load_components(decompose(synthetic_btf(9)), *([torch.zeros(N_DIRS, 3)] * 2))


@pytest.mark.skipif(cpu_kernels.library() is None, reason=f"CPU kernels unavailable: {cpu_kernels.unavailable()}")
def test_fused_kernel_equals_the_torch_formulas(gen):
    """The C kernel (cpu_kernels.pca_btf_eval) against the torch path it replaces: a BTF that is not reciprocal,
    ranks that differ by channel, uv far outside [0, 1) (wrap-around), rows below the horizon and on a bin."""
    btf = non_reciprocal_btf(5)
    model = fit_pca(btf, (6, 3, 2))
    n = 3000
    wi = torch.nn.functional.normalize(torch.randn(n, 3, generator=gen) + torch.tensor([0, 0, 0.8]), dim=-1)
    wo = torch.nn.functional.normalize(torch.randn(n, 3, generator=gen) + torch.tensor([0, 0, 0.8]), dim=-1)
    wi[:20], wo[20:40] = model.light_dirs[torch.arange(20) % N_DIRS], model.view_dirs[torch.arange(20) % N_DIRS]
    q = Query(wi, wo, uv=torch.rand(n, 2, generator=gen) * 5 - 2)
    assert_kernel_equals_torch(model, q)
