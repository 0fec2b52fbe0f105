"""The restructured VQ training step (one grid call for wi and wo, fused straight-through with a coalesced
sparse logits gradient, scratch memory) against the previous formulation, in float64 on a small grid.

Reference (the code before the restructuring): each of the two lookups calls the grid on its own; the grid
takes the unique ids, embeds their logit rows with a dense gradient, and returns D[argmax] forward with the
gradient of softmax(rows) @ D (D held fixed) for the rows and of the hard lookup for D.
"""
from __future__ import annotations

import copy

import pytest
import torch
import torch.nn.functional as F

from neumat.core.errors import InputError
from neumat.core.query import Query
from neumat.methods.neubrdf.model import NeuBRDF
from neumat.nn.codebook import VQFeatures


def _reference_grid(grid: VQFeatures):
    def forward(ids: torch.Tensor) -> torch.Tensor:
        uniq, inv = torch.unique(ids, return_inverse=True)
        rows = F.embedding(uniq, grid.logits)
        hard = grid.codebook[rows.argmax(-1)]
        soft = torch.softmax(rows, -1) @ grid.codebook.detach()
        return (hard + (soft - soft.detach()))[inv]
    return forward


def _reference_features(model: NeuBRDF, q: Query) -> torch.Tensor:
    return torch.cat([model._lookup(q.wi, False), model._lookup(q.wo, True)], -1)


def _models():
    torch.manual_seed(3)
    new = NeuBRDF(nside=4, feature_dim=3, index_bits=4, hidden=8).double()
    ref = NeuBRDF(nside=4, feature_dim=3, index_bits=4, hidden=8).double()
    ref.load_state_dict(new.state_dict())
    ref.grid.forward = _reference_grid(ref.grid)
    return new, ref


def _query(n: int, seed: int) -> tuple[Query, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    wi, wo = (F.normalize(torch.randn(n, 3, generator=g, dtype=torch.float64).abs() + 0.05, dim=-1)
              for _ in range(2))
    return Query(wi, wo), 0.3 + 2 * F.normalize(wi + wo, dim=-1)[:, 2:3] ** 8


def _loss(pred, y, q):
    cos = q.wi[:, 2:3]
    return (torch.log1p(pred * cos) - torch.log1p(y * cos)).abs().mean()


def test_vq_step_equals_the_previous_formulation():
    new, ref = _models()
    opt_new, opt_ref = new.optimizer(1e-2), ref.optimizer(1e-2)
    ref.grid.sparse_grad = False  # the reference's dense logits gradient is made row-sparse below
    for step in range(3):
        q, y = _query(300, step)
        f_new = new.eval(q)
        f_ref = torch.exp(ref.mlp(_reference_features(ref, q)))
        torch.testing.assert_close(f_new, f_ref, rtol=1e-15, atol=0)  # ref: hard + (soft - soft)
        for m, f, opt in ((new, f_new, opt_new), (ref, f_ref, opt_ref)):
            opt.zero_grad(set_to_none=True)
            _loss(f, y, q).backward()
        g_ref = ref.grid.logits.grad
        assert new.grid.logits.grad.is_sparse
        torch.testing.assert_close(new.grid.logits.grad.to_dense(), g_ref, rtol=1e-12, atol=1e-15)
        for a, b in zip(new.parameters(), ref.parameters()):
            if not a.grad.is_sparse:
                torch.testing.assert_close(a.grad, b.grad, rtol=1e-12, atol=1e-15)
        rows = torch.unique(torch.nonzero(g_ref.abs().sum(-1))[:, 0])
        ref.grid.logits.grad = torch.sparse_coo_tensor(rows.unsqueeze(0), g_ref[rows], g_ref.shape,
                                                        check_invariants=True)
        opt_new.step()
        opt_ref.step()
        for a, b in zip(new.parameters(), ref.parameters()):
            torch.testing.assert_close(a, b, rtol=1e-12, atol=1e-14)


def test_backward_regathers_rows_after_another_forward():
    """Two forward passes before one backward (the scratch rows then belong to the second): same gradient."""
    new, ref = _models()
    q1, y1 = _query(200, 7)
    q2, y2 = _query(150, 8)
    for m in (new, ref):
        f1 = m.eval(q1) if m is new else torch.exp(m.mlp(_reference_features(m, q1)))
        f2 = m.eval(q2) if m is new else torch.exp(m.mlp(_reference_features(m, q2)))
        (_loss(f1, y1, q1) + 0.5 * _loss(f2, y2, q2)).backward()
    torch.testing.assert_close(new.grid.logits.grad.to_dense(), ref.grid.logits.grad, rtol=1e-12, atol=1e-15)
    torch.testing.assert_close(new.grid.codebook.grad, ref.grid.codebook.grad, rtol=1e-12, atol=1e-15)


def test_quantize_from_dense_starts_at_the_nearest_codewords():
    torch.manual_seed(0)
    model = NeuBRDF(nside=4, feature_dim=3, index_bits=3, hidden=8, features="dense")
    with torch.no_grad():  # 8 clusters of features: k-means with 8 codewords finds them
        centres = torch.randn(8, 3) * 3
        n = model.grid.num_vertices
        model.grid.features.copy_(centres[torch.arange(n) % 8] + 0.01 * torch.randn(n, 3))
    dense = model.grid.features.detach().clone()
    q, _ = _query(100, 1)
    q = Query(q.wi.float(), q.wo.float())
    before = model.eval(q).detach()
    model.quantize_from_dense()
    assert isinstance(model.grid, VQFeatures) and model.cfg.features == "vq" and model.cfg.index_bits == 3
    feats = model.grid.codebook.detach()[model.grid.indices()]
    used = model.used_slots()
    assert (feats[used] - dense[used]).abs().max() < 0.05
    torch.testing.assert_close(model.eval(q).detach(), before, rtol=0.05, atol=1e-3)
    opt = model.optimizer(1e-2)  # trains as a VQ model from here
    q2, y = _query(64, 2)
    q2 = Query(q2.wi.float(), q2.wo.float())
    _loss(model.eval(q2), y.float(), q2).backward()
    opt.step()


def _two_group_model():
    """A dense NeuBRDF (b 1) whose slot features are (+-1 by slot parity + noise 0.05, uniform in [-10, 10]): plain
    k-means into 2 codewords splits the wide second channel, the groups are told apart by the first."""
    torch.manual_seed(0)
    model = NeuBRDF(nside=4, feature_dim=2, index_bits=1, hidden=8, features="dense")
    n = model.grid.num_vertices
    group = torch.arange(n) % 2
    with torch.no_grad():
        model.grid.features.copy_(torch.stack([group * 2.0 - 1 + 0.05 * torch.randn(n), torch.rand(n) * 20 - 10], -1))
    return model, group


def test_weighted_quantize_from_dense_clusters_by_the_weighted_channels():
    model, group = _two_group_model()
    used = model.used_slots()
    plain = copy.deepcopy(model).quantize_from_dense()
    idx = plain.grid.indices()[used]
    assert 0.3 < float((idx == group[used]).float().mean()) < 0.7  # the plain split ignores the groups
    weights = torch.zeros(model.grid.num_vertices, 2)
    weights[:, 0] = 1.0  # only the first channel matters
    weighted = copy.deepcopy(model).quantize_from_dense(weights=weights, iterations=50)
    idx = weighted.grid.indices()[used]
    assert torch.equal(idx, group[used]) or torch.equal(idx, 1 - group[used])
    code = weighted.grid.codebook.detach()
    feats = model.grid.features.detach()[used]
    for c in (0, 1):  # each codeword is the weighted mean of its slots, channel by channel (Lloyd's fixed point)
        members = feats[idx == c]
        assert abs(float(code[c, 0]) - float(members[:, 0].mean())) < 1e-5
        assert abs(abs(float(code[c, 0])) - 1.0) < 0.02
        # the second channel carries 1e-6 of the mean weight: still the members' mean there
        assert abs(float(code[c, 1]) - float(members[:, 1].mean())) < 1e-3


@pytest.mark.parametrize("weights, why", [(torch.ones(5, 2), "expected a float tensor"),
                                          ("ones", "expected a float tensor"),
                                          (-1.0, "non-negative"), (float("nan"), "finite"), (0.0, "not all 0")])
def test_quantize_from_dense_refuses_bad_weights(weights, why):
    model, _ = _two_group_model()
    if isinstance(weights, float):
        weights = torch.full((model.grid.num_vertices, 2), weights)
    with pytest.raises(InputError, match=why):
        model.quantize_from_dense(weights=weights)
    assert model.cfg.features == "dense"
