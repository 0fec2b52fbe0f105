"""Vertex feature storage: straight-through VQ codebook, dense and low-bit features, storage formula."""
from __future__ import annotations

import pytest
import torch

from neumat.core.errors import InputError
from neumat.nn.codebook import DenseFeatures, LowBitFeatures, VQFeatures, float_bits, storage_bytes


def test_storage_formula_matches_paper_table4():
    v = 2 * (6 * 64 ** 2 + 6 * 64 + 1)  # 2 n at Nside 64
    assert v == 49922
    vq = VQFeatures(v, 16, 9)
    # 2 n b + 16 k 2^b bits (paper Sec. 3.3, fp16)
    assert vq.storage_bits(16) == 49922 * 9 + 16 * 16 * 512 == 580370
    assert storage_bytes(vq.storage_bits(float_bits("fp16"))) == 72547  # paper: 0.07 MB
    assert storage_bytes(DenseFeatures(v, 16).storage_bits(16)) == 1597504  # paper: 1.60 MB
    assert storage_bytes(LowBitFeatures(v, 16, 4).storage_bits(16)) == 399376  # paper: 0.40 MB
    # compression ratio of the paper's formula, dense fp16 over vq
    assert DenseFeatures(v, 16).storage_bits(16) / vq.storage_bits(16) == pytest.approx(16 * v * 16 / 580370)


def test_straight_through_forward_hard_backward_soft(gen):
    vq = VQFeatures(20, 3, 3)
    ids = torch.tensor([[0, 5, 7, 19], [3, 3, 1, 0]])
    out = vq(ids)
    torch.testing.assert_close(out, vq.codebook[vq.logits.argmax(-1)[ids]], rtol=0, atol=1e-7)
    g = torch.randn(out.shape, generator=gen)
    (out * g).sum().backward()
    grad_logits, grad_code = vq.logits.grad.clone(), vq.codebook.grad.clone()
    # reference (float64 autograd): the codebook gets the gradient of the hard lookup D[argmax], the
    # logits that of the soft mixture softmax(logits) @ D with D held fixed
    lg = vq.logits.detach().double().requires_grad_()
    cb = vq.codebook.detach().double().requires_grad_()
    hard = cb[lg.argmax(-1)[ids]]
    soft = torch.softmax(lg[ids], -1) @ cb.detach()
    ((hard + soft) * g.double()).sum().backward()
    torch.testing.assert_close(grad_logits.double(), lg.grad, rtol=1e-4, atol=1e-7)
    torch.testing.assert_close(grad_code.double(), cb.grad, rtol=1e-4, atol=1e-7)
    # the whole-table path (many ids) gives the same values and gradients
    vq.zero_grad()
    many = torch.cat([ids.reshape(-1), torch.arange(20)])
    (vq(many)[:8].reshape(2, 4, 3) * g).sum().backward()
    torch.testing.assert_close(vq.logits.grad, grad_logits, rtol=1e-5, atol=1e-7)


def test_vq_learns_indices_end_to_end():
    torch.manual_seed(0)
    protos = torch.randn(8, 4)
    assign = torch.randint(0, 8, (200,))
    target = protos[assign]
    vq = VQFeatures(200, 4, 4, init_std=0.5)
    opt = torch.optim.Adam(vq.parameters(), lr=0.05)
    ids = torch.arange(200)
    for _ in range(300):
        opt.zero_grad()
        loss = ((vq(ids) - target) ** 2).mean()
        loss.backward()
        opt.step()
    vq.freeze()
    err = ((vq(ids) - target) ** 2).mean().item() / (target ** 2).mean().item()
    assert err < 1e-3, err


def test_freeze_and_state_dict_roundtrip():
    vq = VQFeatures(30, 4, 5)
    ids = torch.randint(0, 30, (50,))
    with torch.no_grad():  # the exact hard lookup (training adds soft - soft, off by rounding)
        before = vq(ids)
    vq.freeze()
    assert vq.frozen and vq.index.dtype == torch.int32
    torch.testing.assert_close(vq(ids), before, rtol=0, atol=0)
    fresh = VQFeatures(30, 4, 5)
    fresh.load_state_dict(vq.state_dict())
    torch.testing.assert_close(fresh(ids), before, rtol=0, atol=0)

    lb = LowBitFeatures(30, 4, 3)
    out = lb(ids)
    levels = (out.detach() + 1) * 7 / 2
    torch.testing.assert_close(levels, levels.round(), rtol=0, atol=1e-5)  # on the 2^3 - 1 grid
    out.sum().backward()
    assert lb.features.grad.abs().sum() > 0  # straight-through rounding passes gradient
    lb.freeze()
    torch.testing.assert_close(lb(ids), out.detach(), rtol=0, atol=1e-6)
    fresh = LowBitFeatures(30, 4, 3)
    fresh.load_state_dict(lb.state_dict())
    torch.testing.assert_close(fresh(ids), out.detach(), rtol=0, atol=1e-6)


def test_bad_input_raises():
    with pytest.raises(InputError, match="bits"):
        VQFeatures(10, 4, 0)
    with pytest.raises(InputError, match="bits"):
        VQFeatures(10, 4, 17)
    with pytest.raises(InputError, match="feature_bits"):
        LowBitFeatures(10, 4, 9)
    with pytest.raises(InputError, match="num_vertices"):
        DenseFeatures(0, 4)
    vq = VQFeatures(10, 4, 2)
    with pytest.raises(InputError, match="ids"):
        vq(torch.tensor([10]))
    with pytest.raises(InputError, match="ids"):
        vq(torch.tensor([0.5]))
    with pytest.raises(InputError, match="precision"):
        float_bits("fp8")


def test_row_adam_matches_adam_dense_and_lazy_on_sparse_rows(gen):
    """Dense gradients: torch.optim.Adam's update. Sparse row gradients: Adam on the rows present (equal to
    dense Adam while every row is present), other rows and their moments untouched."""
    from neumat.nn.row_adam import RowAdam

    w0 = torch.randn(6, 4, generator=gen)
    dense, sparse, ref = (torch.nn.Parameter(w0.clone()) for _ in range(3))
    opt_ref = torch.optim.Adam([ref], lr=0.1, betas=(0.8, 0.9), eps=1e-6)
    opt = RowAdam([dense, sparse], lr=0.1, betas=(0.8, 0.9), eps=1e-6)
    all_rows = torch.arange(6)
    for _ in range(3):
        g = torch.randn(6, 4, generator=gen)
        for p in (dense, ref):
            p.grad = g.clone()
        sparse.grad = torch.sparse_coo_tensor(all_rows[None], g, (6, 4), check_invariants=True)
        opt_ref.step()
        opt.step()
    torch.testing.assert_close(dense, ref, rtol=1e-6, atol=1e-7)
    torch.testing.assert_close(sparse, ref, rtol=1e-5, atol=1e-6)
    before, m_before = sparse.detach().clone(), opt.state[sparse]["exp_avg"].clone()
    rows = torch.tensor([1, 4])
    sparse.grad = torch.sparse_coo_tensor(rows[None], torch.randn(2, 4, generator=gen), (6, 4), check_invariants=True)
    opt.step()
    moved = (sparse.detach() != before).any(-1)
    assert moved.tolist() == [False, True, False, False, True, False]
    assert torch.equal(opt.state[sparse]["exp_avg"][[0, 2, 3, 5]], m_before[[0, 2, 3, 5]])


def test_vq_sparse_gradient_equals_dense(gen):
    vq = VQFeatures(40, 3, 4)
    ids = torch.randint(0, 40, (25, 4), generator=gen)
    g = torch.randn(25, 4, 3, generator=gen)
    (vq(ids) * g).sum().backward()
    dense_grad = vq.logits.grad.clone()
    vq.zero_grad(set_to_none=True)
    vq.sparse_grad = True
    (vq(ids) * g).sum().backward()
    assert vq.logits.grad.is_sparse
    torch.testing.assert_close(vq.logits.grad.to_dense(), dense_grad)


def _restricted_pair(candidates: torch.Tensor, seed: int = 0):
    """A VQ grid and a copy of it restricted to `candidates`, in float64."""
    torch.manual_seed(seed)
    full = VQFeatures(12, 3, 3).double()
    part = VQFeatures(12, 3, 3).double()
    part.load_state_dict(full.state_dict())
    part.restrict(candidates)
    return full, part


def test_restricting_to_every_codeword_is_the_full_estimator(gen):
    # all 8 codewords in a different order per vertex: a permutation of the logits, so the same forward pass
    # and the same gradients (permuted) as the full straight-through estimator
    perm = torch.stack([torch.randperm(8, generator=gen) for _ in range(12)])
    full, part = _restricted_pair(perm)
    ids = torch.tensor([[0, 5, 7, 11], [3, 3, 1, 0]])
    g = torch.randn(2, 4, 3, generator=gen, dtype=torch.float64)
    (full(ids) * g).sum().backward()
    out = part(ids)
    (out * g).sum().backward()
    torch.testing.assert_close(out, full(ids).detach(), rtol=0, atol=0)
    torch.testing.assert_close(part.logits.grad, full.logits.grad.gather(1, perm), rtol=1e-12, atol=1e-14)
    torch.testing.assert_close(part.codebook.grad, full.codebook.grad, rtol=1e-12, atol=1e-14)
    torch.testing.assert_close(part.indices(), full.indices(), rtol=0, atol=0)


def test_restricted_straight_through_matches_a_masked_softmax(gen):
    # K = 3 candidates: the reference is the full estimator with every other codeword's logit at -inf
    cand = torch.stack([torch.randperm(8, generator=gen)[:3] for _ in range(12)])
    full, part = _restricted_pair(cand, seed=1)
    masked = torch.full_like(full.logits, -torch.inf).scatter(1, cand, full.logits.detach().gather(1, cand))
    lg = masked.clone().requires_grad_()
    ids = torch.tensor([2, 2, 9, 4, 11, 0])
    g = torch.randn(6, 3, generator=gen, dtype=torch.float64)
    cb = full.codebook.detach().clone().requires_grad_()
    hard = cb[lg.argmax(-1)[ids]]
    soft = torch.softmax(lg[ids], -1) @ cb.detach()
    ((hard + soft - soft.detach()) * g).sum().backward()
    out = part(ids)
    (out * g).sum().backward()
    torch.testing.assert_close(out, hard.detach(), rtol=0, atol=0)
    torch.testing.assert_close(part.logits.grad, lg.grad.gather(1, cand), rtol=1e-12, atol=1e-14)
    torch.testing.assert_close(part.codebook.grad, cb.grad, rtol=1e-12, atol=1e-14)
    # no gradient without grad, sparse rows with sparse_grad, and the frozen indices are the chosen candidates
    with torch.no_grad():
        torch.testing.assert_close(part(ids), out.detach(), rtol=0, atol=0)
    part.zero_grad()
    part.sparse_grad = True
    (part(ids) * g).sum().backward()
    torch.testing.assert_close(part.logits.grad.to_dense(), lg.grad.gather(1, cand), rtol=1e-12, atol=1e-14)
    chosen = cand.gather(1, part.logits.detach().argmax(-1, keepdim=True)).squeeze(-1)
    part.freeze()
    torch.testing.assert_close(part.index.long(), chosen, rtol=0, atol=0)
    assert part.candidates is None


def test_restricted_state_round_trips_into_a_fresh_grid(gen):
    cand = torch.stack([torch.randperm(8, generator=gen)[:2] for _ in range(12)])
    _, part = _restricted_pair(cand, seed=2)
    fresh = VQFeatures(12, 3, 3).double()
    fresh.load_state_dict(part.state_dict())
    torch.testing.assert_close(fresh.candidates, cand, rtol=0, atol=0)
    ids = torch.arange(12)
    torch.testing.assert_close(fresh(ids), part(ids), rtol=0, atol=0)


@pytest.mark.parametrize("bad, match", [
    (torch.zeros(11, 2, dtype=torch.long), r"expected integer candidates \(12, K\)"),
    (torch.zeros(12, 9, dtype=torch.long), "1 <= K <= 8"),
    (torch.full((12, 2), 8), r"must lie in \[0, 8\)"),
    (torch.zeros(12, 2, dtype=torch.long), "same candidate codeword twice"),
    (torch.zeros(12, 2), "expected integer candidates"),
])
def test_restrict_refuses_bad_candidates(bad, match):
    with pytest.raises(InputError, match=match):
        VQFeatures(12, 3, 3).restrict(bad)
    vq = VQFeatures(12, 3, 3)
    vq.restrict(torch.arange(2).repeat(12, 1))
    with pytest.raises(InputError, match="already restricted"):
        vq.restrict(torch.arange(2).repeat(12, 1))
