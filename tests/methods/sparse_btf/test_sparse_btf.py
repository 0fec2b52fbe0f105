"""SparseBTF: dictionary-ensemble training, sparse coding, Eq. 5/6 reconstruction, Eq. 7-9 blending, storage."""
from __future__ import annotations

import pytest
import torch
from safetensors import safe_open
from safetensors.torch import load_file, save_file

from neumat import DataFormatError, InputError, Query
from neumat.catalog.modelfile import load_model, save_model
from neumat.io.modelfile import read_model_file
from neumat.methods.sparse_btf.model import SparseBTF, _pairs_of_taps, mse, storage_bytes
from neumat.methods.sparse_btf.dictionary_train import train_dictionary, train_ensemble
from neumat.methods.sparse_btf.dictionary import (BTFDictionary, code_points, code_points_at_rates, decode_points,
                                             keep_largest, mode_product, model_space_to_rgb, prepare_btf, project,
                                             rgb_to_model_space)
from neumat.nn import cpu_kernels
from neumat.reflectance.btf import angular_weights, direction_set

from btf_util import N_DIRS, SIZE, assert_kernel_equals_torch, non_reciprocal_btf, synthetic_btf

PATCH = 4


def random_queries(n: int, gen: torch.Generator) -> Query:
    """n queries with directions mostly above the horizon and uniform uv."""
    wi = torch.nn.functional.normalize(torch.rand(n, 3, generator=gen) - torch.tensor([0.5, 0.5, -0.3]), dim=-1)
    wo = torch.nn.functional.normalize(torch.rand(n, 3, generator=gen) - torch.tensor([0.5, 0.5, -0.3]), dim=-1)
    return Query(wi, wo, uv=torch.rand(n, 2, generator=gen))


@pytest.fixture(scope="module")
def trained() -> BTFDictionary:
    return train_dictionary([synthetic_btf(s) for s in (1, 2, 3)], num_dictionaries=2, tau_train=(24, 8, 8),
                            patch=PATCH, max_iters=8, seed=0)


def test_model_space_round_trip_and_no_negative_values(gen):
    rgb = torch.rand(1000, 3, generator=gen, dtype=torch.float64) * 10
    rgb[:10] = 0
    assert torch.allclose(model_space_to_rgb(rgb_to_model_space(rgb, 0.01), 0.01), rgb, atol=1e-12)
    yuv = rgb_to_model_space(rgb, 0.01) + torch.randn(1000, 3, generator=gen, dtype=torch.float64)
    back = model_space_to_rgb(yuv, 0.01)
    unclamped = torch.exp(yuv @ torch.linalg.inv(torch.tensor([[0.299, 0.587, 0.114], [-0.14713, -0.28886, 0.436],
                                                               [0.615, -0.51499, -0.10001]], dtype=torch.float64)).T)
    assert (unclamped < 0.01).any()                               # errors that would give negative values ...
    assert torch.allclose(back, (unclamped - 0.01).clamp(min=0), rtol=1e-12, atol=0)
    assert (back[unclamped < 0.01] == 0).all()                    # ... are clamped to 0, the rest unchanged


def test_mode_product_matches_einsum_for_every_mode(gen):
    x = torch.randn(3, 2, 3, 4, 5, generator=gen, dtype=torch.float64)
    letters = "abcd"
    for mode in range(1, 5):
        m = x.shape[mode]
        u = torch.randn(m + 1, m, generator=gen, dtype=torch.float64)          # one matrix, or one per point
        per_point = torch.randn(3, m + 1, m, generator=gen, dtype=torch.float64)
        src = "n" + letters
        dst = src.replace(letters[mode - 1], "z")
        assert torch.allclose(mode_product(x, u, mode), torch.einsum(f"z{letters[mode - 1]},{src}->{dst}", u, x))
        assert torch.allclose(mode_product(x, per_point, mode),
                              torch.einsum(f"nz{letters[mode - 1]},{src}->{dst}", per_point, x))


def test_training_keeps_orthonormality_and_objective_decreases(trained):
    for ens in trained.ensembles:
        assert ens.orthonormality_error() < 1e-5
    for obj in trained.info["objective"].values():
        assert all(b <= a * (1 + 1e-6) for a, b in zip(obj, obj[1:]))


def test_training_beats_its_initialisation_on_structured_data(gen):
    base = [torch.linalg.qr(torch.randn(m, m, generator=gen))[0][:, :2] for m in (4, 4, 6, 6)]
    x = torch.einsum("nabcd,ia,jb,kc,ld->nijkl", torch.randn(40, 2, 2, 2, 2, generator=gen), *base)
    x = x + 0.01 * torch.randn(x.shape, generator=gen)
    ens, log = train_ensemble(x, 2, tau=16, max_iters=10)
    assert log.objective[-1] <= log.objective[0]
    assert ens.orthonormality_error() < 1e-5
    # the planted 2x2x2x2 structure is recovered: 16 coefficients leave only the noise
    codes = code_points(x, ens, 16)
    assert float(codes.error.mean()) < 3 * 0.01 ** 2


def test_all_coefficients_reconstruct_exactly(trained):
    btf = synthetic_btf(7)
    full = SparseBTF.encode(btf, trained, tau=PATCH * PATCH * N_DIRS * N_DIRS)
    assert mse(btf, full.decode()) < 1e-9
    points, _, _ = prepare_btf(btf.data, PATCH, trained.log_eps)
    codes = code_points(points[0], trained.ensembles[0], 10 ** 9)
    assert torch.allclose(decode_points(codes, trained.ensembles[0]), points[0], atol=1e-4)


def test_error_falls_monotonically_with_tau(trained):
    btf = synthetic_btf(8)
    points, _, _ = prepare_btf(btf.data, PATCH, trained.log_eps)
    model_err, linear_err = [], []
    for tau in (24, 48, 96, 192, 384):
        codes = code_points(points[0], trained.ensembles[0], tau)
        model_err.append(float(codes.error.mean()))
        linear_err.append(mse(btf, SparseBTF.encode(btf, trained, (tau, 8 + tau // 8, 8 + tau // 8)).decode()))
    assert all(b < a for a, b in zip(model_err, model_err[1:]))
    assert all(b < a for a, b in zip(linear_err, linear_err[1:])), linear_err


def _brute_force_codes(x: torch.Tensor, ens, tau: int, threshold: float) -> tuple[list, list, list]:
    """Per point and dictionary: project, keep the tau largest, pick the sparsest then lowest-error."""
    membership, counts, errors = [], [], []
    for point in x:
        options = []
        for k in range(ens.size):
            s = project(point[None], ens.dictionary(k)).reshape(1, -1)
            _, _, count, err = keep_largest(s, tau, threshold)
            options.append((int(count), float(err), k))
        count, err, k = min(options)
        membership.append(k)
        counts.append(count)
        errors.append(err)
    return membership, counts, errors


@pytest.mark.parametrize("threshold", [0.0, 0.05])
def test_coding_several_rates_at_once_equals_coding_each(trained, threshold):
    btf = synthetic_btf(8)
    points, _, _ = prepare_btf(btf.data, PATCH, trained.log_eps)
    taus = (8, 24, 96)
    for codes, tau in zip(code_points_at_rates(points[0], trained.ensembles[0], taus, threshold, chunk=3), taus):
        membership, counts, errors = _brute_force_codes(points[0], trained.ensembles[0], tau, threshold)
        assert codes.membership.tolist() == membership
        assert codes.counts.tolist() == counts
        assert torch.allclose(codes.error, torch.tensor(errors), rtol=1e-5, atol=1e-7)
    models = SparseBTF.encode_rates(btf, trained, [(24, 8, 8), 48], error_threshold=threshold)
    for model, tau in zip(models, [(24, 8, 8), 48]):
        single = SparseBTF.encode(btf, trained, tau, error_threshold=threshold)
        assert model.cfg == single.cfg
        assert all(torch.equal(a, b) for a, b in zip(model.state_dict().values(), single.state_dict().values()))
    with pytest.raises(InputError, match="no tau"):
        SparseBTF.encode_rates(btf, trained, [])


def test_element_reconstruction_matches_full_decode(trained, gen):
    model = SparseBTF.encode(synthetic_btf(9), trained, (40, 10, 10))
    dense = model.decode_points()                                           # (3, P, p, p, L, V)
    n = 50
    idx = [torch.randint(0, s, (n,), generator=gen) for s in dense.shape[1:]]
    for c in range(3):
        assert torch.allclose(model.element(c, *idx), dense[c][tuple(idx)], atol=1e-5)


def _bins(model: SparseBTF, n: int, k: int, gen: torch.Generator):
    """The k nearest light and view bins and weights (li, lw, vi, vw), each (n, k), of n random upper
    directions."""
    wi = torch.nn.functional.normalize(torch.rand(n, 3, generator=gen) + torch.tensor([0, 0, 1.0]), dim=-1)
    wo = torch.nn.functional.normalize(torch.rand(n, 3, generator=gen) + torch.tensor([0, 0, 1.0]), dim=-1)
    return (*angular_weights(model.light_dirs, wi, k), *angular_weights(model.view_dirs, wo, k))


def test_coefficient_space_interpolation_equals_value_interpolation(trained, gen):
    model = SparseBTF.encode(synthetic_btf(10), trained, (40, 10, 10))
    n, k = 30, 3
    li, lw, vi, vw = _bins(model, n, k, gen)
    patch, x1, x2 = (torch.randint(0, s, (n,), generator=gen) for s in (model.counts.shape[1], PATCH, PATCH))
    for c in range(3):
        eq6 = model.element_interpolated(c, patch, x1, x2, li, lw, vi, vw)
        values = torch.stack([torch.stack([model.element(c, patch, x1, x2, li[:, a], vi[:, b]) for b in range(k)], -1)
                              for a in range(k)], -2)                       # (n, kl, kv)
        ref = (values * lw[:, :, None] * vw[:, None, :]).sum((1, 2))
        assert torch.allclose(eq6, ref, atol=1e-5)


def test_merged_taps_equal_eq6_per_element(trained, gen):
    model = SparseBTF.encode(synthetic_btf(10), trained, (40, 10, 10))
    n, k = 200, 3
    li, lw, vi, vw = _bins(model, n, k, gen)
    patch, x1, x2, tap_w = model._texels(torch.rand(n, 2, generator=gen) * 3 - 1)
    assert len(set(model.membership[0].tolist())) > 1           # the taps use more than one dictionary
    data_points = torch.tensor([len(set(row)) for row in patch.tolist()])
    assert set(data_points.tolist()) == {1, 2, 4}               # taps within one, across one or two patch edges
    expand = lambda t: t[:, None].expand(-1, 4, -1)             # noqa: E731
    pairs = _pairs_of_taps(patch)
    for c in range(3):
        ref = model.element_interpolated(c, patch, x1, x2, expand(li), expand(lw), expand(vi), expand(vw))
        got = model._texel_sum_interpolated(c, pairs, x1, x2, tap_w, li, lw, vi, vw)
        assert torch.allclose(got, (ref * tap_w).sum(1), atol=1e-6)
        # the value-space path: Eq. 5 at every tap and bin pair
        bins = model._texel_bins(c, pairs, x1, x2, li, vi)                      # (n, 4, k, k)
        shape = (n, 4, k, k)
        eq5 = model.element(c, *(t[:, :, None, None].expand(shape) for t in (patch, x1, x2)),
                            li[:, None, :, None].expand(shape), vi[:, None, None, :].expand(shape))
        assert torch.allclose(bins, eq5, atol=1e-6)


def test_eval_in_batches_equals_one_batch(trained, gen):
    model = SparseBTF.encode(synthetic_btf(10), trained, (40, 10, 10))
    n = 300
    q = random_queries(n, gen)
    for angular in ("coefficient", "value"):
        model.cfg.angular = angular
        whole = model.eval(q, batch=n)
        assert torch.allclose(model.eval(q, batch=7), whole, rtol=1e-5, atol=1e-7)  # summation order differs
        assert torch.allclose(model.eval(q), whole, rtol=1e-5, atol=1e-7)           # default batch size
        assert model.eval(q[:0]).shape == (0, 3)
    with pytest.raises(InputError, match="batch"):
        model.eval(q, batch=0)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA (the batched reconstruction's GPU path)")
def test_cuda_reconstruction_gives_the_cpu_numbers(trained, gen):
    model = SparseBTF.encode(synthetic_btf(10), trained, (40, 10, 10))
    n = 500
    q = random_queries(n, gen)
    for angular in ("coefficient", "value"):
        model.cfg.angular = angular
        cpu = model.to("cpu").eval(q)
        gpu = model.to("cuda").eval(q.to("cuda"))
        assert gpu.device.type == "cuda"
        torch.testing.assert_close(gpu.cpu(), cpu, rtol=1e-4, atol=1e-6)


def test_value_space_eval_equals_the_decoded_table(trained, gen):
    model = SparseBTF.encode(synthetic_btf(11), trained, (40, 10, 10), angular="value")
    n = 64
    q = random_queries(n, gen)
    assert torch.allclose(model.eval(q), model.decode().eval(q), rtol=1e-4, atol=1e-5)
    # the coefficient-space path interpolates in model space; at bin directions and texel centres the
    # weights are one-hot and both paths return the decoded table entry
    fast = SparseBTF.encode(synthetic_btf(11), trained, (40, 10, 10))
    li, vi = torch.randint(0, N_DIRS, (2, n), generator=gen)
    rows, cols = torch.randint(0, SIZE, (2, n), generator=gen)
    uv = torch.stack([(cols + 0.5) / SIZE, 1 - (rows + 0.5) / SIZE], -1)
    q = Query(model.light_dirs[li], model.view_dirs[vi], uv=uv)
    table = model.decode().data[li, vi, rows, cols]
    assert torch.allclose(fast.eval(q), table, rtol=1e-4, atol=1e-5)
    assert torch.allclose(model.eval(q), table, rtol=1e-4, atol=1e-5)


def test_blending_same_and_different_dictionaries(trained):
    a = SparseBTF.encode(synthetic_btf(12), trained, (40, 10, 10))
    b = SparseBTF.encode(synthetic_btf(13), trained, (40, 10, 10))
    alpha = 0.3
    mixed = SparseBTF.blend(a, b, alpha)
    expect = (1 - alpha) * a.decode_points() + alpha * b.decode_points()
    # Eq. 8-9 change of basis is exact with enough coefficients, whatever the memberships
    exact = SparseBTF.blend(a, b, alpha, tau=(10 ** 6,) * 3)
    assert torch.allclose(exact.decode_points(), expect, atol=1e-4)
    same = a.membership == b.membership
    assert bool(same.any())
    got = mixed.decode_points()
    for c in range(3):
        assert torch.allclose(got[c][same[c]], expect[c][same[c]], atol=1e-4)
    assert torch.allclose(mixed.mean, (1 - alpha) * a.mean + alpha * b.mean)


def test_storage_accounting(trained):
    model = SparseBTF.encode(synthetic_btf(14), trained, (40, 10, 10))
    st = model.storage()
    points = (SIZE // PATCH) ** 2
    assert st["coefficients"] == points * 60
    assert st["values"] == 2 * st["coefficients"] and st["indices"] == 8 * st["coefficients"]
    assert st["membership"] == st["counts"] == 2 * 3 * points
    assert st["dictionary"] == 3 * 2 * (2 * PATCH ** 2 + 2 * N_DIRS ** 2) * 2
    assert model.size_bytes() == st["total"]
    thr = SparseBTF.encode(synthetic_btf(14), trained, (400, 100, 100), error_threshold=1e-2)
    assert int(thr.counts.sum()) < 600 * points
    assert thr.storage()["coefficients"] == int(thr.counts.sum())
    # capacity (storage_bytes without nnz: every data point at tau): what a coding at full tau takes, an upper bound
    capacity = storage_bytes(model.cfg)
    assert capacity == st
    assert storage_bytes(thr.cfg)["per_btf"] > thr.storage()["per_btf"]


def test_stored_float16_parts_keep_the_coding_error(trained):
    """Storage charges values, dictionaries and (with statistics_bytes=2) the statistics at float16 while the
    model keeps float32: rounding them changes the reconstruction far less than the coding error does."""
    btf = synthetic_btf(19)
    model = SparseBTF.encode(btf, trained, (40, 10, 10))
    rounded = SparseBTF(config=model.cfg)
    rounded.load_state_dict(model.state_dict())
    for name in ("values", "dict_1", "dict_2", "dict_3", "dict_4", "mean", "std"):
        buffer = getattr(rounded, name)
        buffer.copy_(buffer.half().float())
    exact = model.decode()
    error = mse(btf, exact)
    assert mse(exact, rounded.decode()) < 1e-3 * error
    assert abs(mse(btf, rounded.decode()) - error) < 1e-2 * error
    st, st16 = model.storage(), model.storage(statistics_bytes=2)
    assert st["statistics"] == 2 * st16["statistics"] == 2 * N_DIRS * N_DIRS * 3 * 4
    assert st["per_btf"] - st16["per_btf"] == st16["statistics"]


def test_per_btf_statistics(trained, gen):
    """Config.statistics "btf": one mean and deviation per channel (6 stored numbers), the codes still
    reconstruct the BTF exactly with every coefficient, and eval, decode and a saved state agree."""
    btf = synthetic_btf(20)
    model = SparseBTF.encode(btf, trained, (40, 10, 10), statistics="btf")
    assert model.storage()["statistics"] == 2 * 3 * 4 and model.storage(statistics_bytes=2)["statistics"] == 12
    assert torch.equal(model.mean, model.mean[:1, :1].expand_as(model.mean))
    yuv = rgb_to_model_space(btf.data.float(), trained.log_eps)
    torch.testing.assert_close(model.mean[0, 0], yuv.mean(dim=(0, 1, 2, 3)))
    torch.testing.assert_close(model.std[0, 0], yuv.std(dim=(0, 1, 2, 3), unbiased=False))
    full = SparseBTF.encode(btf, trained, tau=PATCH * PATCH * N_DIRS * N_DIRS, statistics="btf")
    assert mse(btf, full.decode()) < 1e-9
    again = SparseBTF(config=model.cfg)
    again.load_state_dict(model.state_dict())
    q = Query(model.light_dirs[:5], model.view_dirs[:5], uv=torch.rand(5, 2, generator=gen))
    assert torch.equal(again.eval(q), model.eval(q))
    with pytest.raises(InputError, match="statistics"):
        SparseBTF.encode(btf, trained, statistics="texel")
    # a dictionary trained on points standardised the same way records it
    own = train_dictionary([btf], num_dictionaries=1, tau_train=(24, 8, 8), patch=PATCH, max_iters=2,
                           statistics="btf")
    assert own.info["statistics"] == "btf"
    assert mse(btf, SparseBTF.encode(btf, own, (40, 10, 10), statistics="btf").decode()) < mse(
        btf, SparseBTF.encode(btf, trained, (40, 10, 10), statistics="btf").decode())


def test_state_dict_round_trip(trained, gen):
    model = SparseBTF.encode(synthetic_btf(15), trained, (40, 10, 10))
    again = SparseBTF(config=model.cfg)
    again.load_state_dict(model.state_dict())
    q = Query(model.light_dirs[:5], model.view_dirs[:5], uv=torch.rand(5, 2, generator=gen))
    assert torch.equal(again.eval(q), model.eval(q))


def test_dictionary_file_round_trip(tmp_path, trained):
    back = BTFDictionary.load(trained.save(tmp_path / "dict.nmat"))
    assert back.tau_train == trained.tau_train and back.patch == trained.patch
    for a, b in zip(back.ensembles, trained.ensembles):
        assert all(torch.equal(x, y) for x, y in zip(a.mats, b.mats))


def test_bad_input_is_refused(trained):
    with pytest.raises(InputError, match="tau_t >= tau_l"):
        SparseBTF.encode(synthetic_btf(16), trained, (8, 8, 8))
    other = synthetic_btf(17, dirs=direction_set(13))
    with pytest.raises(InputError, match="angular resolution"):
        SparseBTF.encode(other, trained)
    with pytest.raises(InputError, match="patches"):
        SparseBTF.encode(synthetic_btf(18, size=10), trained)
    with pytest.raises(InputError, match="another direction set"):
        train_dictionary([synthetic_btf(1), other], num_dictionaries=1, tau_train=(4, 4, 4), patch=PATCH)


def test_renders_a_btf_textured_plane(trained):
    from neumat.render.render import render
    model = SparseBTF.encode(synthetic_btf(11), trained, (40, 10, 10))
    img = render(model, scene="plane", light="env:sky", spp=4, resolution=16)
    assert img.shape == (16, 16, 3)
    assert bool(torch.isfinite(img).all()) and float(img.mean()) > 1e-3


def test_runtime_file_holds_the_counted_bytes_and_evaluates_alike(trained, gen, tmp_path):
    model = SparseBTF.encode(synthetic_btf(10), trained, (40, 10, 10), error_threshold=1e-3).runtime()
    assert int(model.counts.sum()) < model.counts.numel() * 40  # the threshold leaves capacity unused
    path = save_model(model, tmp_path / "s.nmat")
    tensors = read_model_file(path)[1]
    stored = sum(t.numel() * t.element_size() for t in tensors.values())
    directions = sum(t.numel() * 4 for k, t in tensors.items() if k.endswith("_dirs"))
    assert stored - directions == model.size_bytes("fp16")  # exactly what `storage` counts
    loaded = load_model(path)
    assert loaded.is_runtime
    q = Query(wi=torch.tensor([[0.0, 0.0, 1.0]] * 5), wo=torch.tensor([[0.0, 0.6, 0.8]] * 5),
              uv=torch.rand(5, 2, generator=gen))
    assert torch.equal(model.eval(q), loaded.eval(q))


def test_stored_codes_that_disagree_with_their_counts_are_refused(trained, tmp_path):
    path = save_model(SparseBTF.encode(synthetic_btf(10), trained, (40, 10, 10)), tmp_path / "s.nmat")
    with safe_open(str(path), "pt") as f:
        metadata = f.metadata()
    tensors = load_file(str(path))
    tensors["values"] = tensors["values"][:-1]
    save_file(tensors, str(path), metadata=metadata)
    with pytest.raises(DataFormatError, match="counts add up to"):
        load_model(path)


@pytest.mark.skipif(cpu_kernels.library() is None, reason=f"CPU kernels unavailable: {cpu_kernels.unavailable()}")
def test_fused_kernel_equals_the_torch_formulas(trained, gen):
    """The C kernel (cpu_kernels.sparse_btf_eval) against the torch path it replaces: a BTF that is not reciprocal
    (light and view bins play different roles) and whose codes use all four modes, queries with uv far outside [0, 1)
    (wrap-around; taps in one and in several data points), some below the horizon and some on a bin exactly."""
    btf = non_reciprocal_btf(5)
    model = SparseBTF.encode(btf, trained, tau=(24, 8, 8))
    q = random_queries(3000, gen)
    wi, wo = q.wi.clone(), q.wo.clone()
    wi[:20], wo[20:40] = model.light_dirs[torch.arange(20) % N_DIRS], model.view_dirs[torch.arange(20) % N_DIRS]
    wi[40:60, 2], wo[50:70, 2] = -wi[40:60, 2], -wo[50:70, 2]
    q = Query(wi, wo, uv=q.uv * 5 - 2)
    assert_kernel_equals_torch(model, q)
    value_space = SparseBTF.encode(btf, trained, tau=(24, 8, 8), angular="value")
    before = cpu_kernels.calls[0]
    value_space.eval(q)
    assert cpu_kernels.calls[0] == before  # value-space interpolation keeps the torch path
