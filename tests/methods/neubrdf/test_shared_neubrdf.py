"""Shared codebooks across materials: storage accounting, equivalence with NeuBRDF for one material, material
views and MaterialQuery, autoencoder + k-means clustering, and a joint fit through the shared trainer."""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import torch

from neumat.core.errors import InputError
from neumat.core.query import Query
from neumat.fit.method import recipe_for
from neumat.metrics.hdr import reflectance_errors
from neumat.methods.neubrdf.model import NeuBRDF
from neumat.models.registry import model_class
from neumat.methods.neubrdf.shared_targets import Clustering, JointSource, cluster_materials, fit_clusters, fit_shared
from neumat.methods.neubrdf.shared_model import Config, MaterialQuery, SharedNeuBRDF, sharing_cost
from neumat.nn import cpu_kernels
from neumat.nn.conv_autoencoder import ConvAutoencoder, train_autoencoder
from neumat.reflectance.analytic import GGX, Plastic
from neumat.warp.hemisphere import sample_cosine_hemisphere

SMALL = dict(nside=4, index_bits=5, hidden=16)


def _queries(n: int, gen: torch.Generator) -> Query:
    return Query(sample_cosine_hemisphere(torch.rand(n, 2, generator=gen)),
                 sample_cosine_hemisphere(torch.rand(n, 2, generator=gen)))


def test_sharing_cost_formula():
    # paper defaults, t = 10: 2n = 49922 slots of 9 bits; codebook 512 x 16 and MLP 32-64-64-3 in fp16
    mlp = (32 * 64 + 64) + (64 * 64 + 64) + (64 * 3 + 3)
    cost = sharing_cost(Config(num_materials=10))
    assert cost.separate_per_material == math.ceil((49922 * 9 + 16 * 16 * 512 + 16 * mlp) / 8) == 85481
    assert cost.shared_per_material == math.ceil((10 * 49922 * 9 + 16 * 16 * 512 + 16 * mlp) / 8) / 10 == 59094.1
    assert cost.ratio == pytest.approx(85481 / 59094.1)
    # against the models' own size_bytes
    small = Config(num_materials=3, **SMALL)
    assert SharedNeuBRDF(config=small).size_bytes("fp32") == 3 * sharing_cost(small, "fp32").shared_per_material
    single = NeuBRDF(**SMALL)
    assert sharing_cost(small).separate_per_material == single.size_bytes("fp16")
    assert SharedNeuBRDF(num_materials=1, **SMALL).size_bytes() == single.size_bytes()
    assert SharedNeuBRDF(num_materials=3, **SMALL).material(2).size_bytes() == sharing_cost(small).shared_per_material


@pytest.mark.parametrize("inputs", ["none", "hd", "hd_warp"])
def test_one_material_equals_neubrdf(gen, inputs):
    """One material is NeuBRDF, with or without direction inputs (their bytes included)."""
    torch.manual_seed(0)
    ref = NeuBRDF(**SMALL, direction_inputs=inputs)
    shared = SharedNeuBRDF(num_materials=1, **SMALL, direction_inputs=inputs)
    assert sharing_cost(shared.cfg).separate_per_material == shared.size_bytes() == ref.size_bytes()
    shared.grid.load_state_dict(ref.grid.state_dict())
    shared.mlp.load_state_dict(ref.mlp.state_dict())
    wi, wo = _queries(50, gen).wi[:20], _queries(50, gen).wo[:20]
    ref.prune(wi, wo)
    shared.prune(0, wi, wo)
    q = _queries(400, gen)
    for p in ref.mlp.parameters():  # an MLP on which the direction inputs matter
        p.data.add_(0.3 * torch.randn(p.shape, generator=gen))
    shared.mlp.load_state_dict(ref.mlp.state_dict())
    torch.testing.assert_close(shared.eval(q), ref.eval(q), rtol=1e-6, atol=0)
    assert shared.flops() == ref.flops()
    with pytest.raises(InputError, match="direction_inputs"):
        SharedNeuBRDF(num_materials=1, **SMALL, direction_inputs="nbrdf")


def test_views_material_queries_and_rebuild(gen):
    torch.manual_seed(0)
    model = model_class("shared-neubrdf")(num_materials=3, **SMALL)
    q = _queries(90, gen)
    ids = torch.arange(90) % 3
    mixed = model.eval(MaterialQuery(q.wi, q.wo, material=ids))
    for i in range(3):
        rows = ids == i
        torch.testing.assert_close(mixed[rows], model.material(i).eval(q[rows]))
    assert not torch.allclose(model.material(0).eval(q), model.material(1).eval(q))
    torch.testing.assert_close(model.select(2).eval(q), model.material(2).eval(q))
    mq = MaterialQuery(q.wi, q.wo, material=ids)
    assert torch.equal(mq[5:9].material, ids[5:9]) and mq.to(dtype=torch.float64).material.dtype == torch.int64
    # rebuild from the config, then frozen indices load into a fresh model
    model.freeze()
    again = SharedNeuBRDF(config=model.cfg)
    again.load_state_dict(model.state_dict())
    torch.testing.assert_close(again.eval(mq), model.eval(mq))
    with pytest.raises(InputError):
        model.material(3)
    with pytest.raises(InputError):
        model.eval(MaterialQuery(q.wi, q.wo, material=ids + 1))
    with pytest.raises(InputError):
        MaterialQuery(q.wi, q.wo, material=ids.float())
    with pytest.raises(InputError):
        SharedNeuBRDF(num_materials=0)
    with pytest.raises(InputError):
        SharedNeuBRDF(nside=6)


def test_autoencoder_shapes_and_training():
    ae = ConvAutoencoder(channels=3, resolution=8, code_dim=4, width=4)
    x = torch.rand(5, 3, 8, 8, 8, generator=torch.Generator().manual_seed(0))
    assert ae.encode(x).shape == (5, 4) and ae(x).shape == x.shape
    losses = train_autoencoder(ae, x, steps=60, lr=1e-2)
    assert losses[-1] < 0.5 * losses[0]
    with pytest.raises(InputError):
        ae.encode(torch.rand(5, 3, 4, 4, 4))
    with pytest.raises(InputError):
        ConvAutoencoder(resolution=12)


def test_cluster_materials_separates_diffuse_from_metallic():
    materials = [Plastic(diffuse=(0.6, 0.3, 0.15), roughness=0.4), GGX(roughness=0.15, fresnel="schlick",
                 f0=(0.95, 0.8, 0.5)), Plastic(diffuse=(0.3, 0.5, 0.4), roughness=0.5),
                 GGX(roughness=0.2, fresnel="schlick", f0=(0.9, 0.9, 0.9))]
    result = cluster_materials(materials, 2, resolution=8, code_dim=4, width=8, steps=150)
    assert result.codes.shape == (4, 4)
    assert sorted(result.groups) == [[0, 2], [1, 3]]
    assert result.labels[0] == result.labels[2] != result.labels[1] == result.labels[3]
    assert np.isfinite(result.reconstruction_mse)
    with pytest.raises(InputError):
        cluster_materials(materials, 5)


def test_joint_fit_through_the_shared_trainer():
    materials = [Plastic(diffuse=(0.6, 0.3, 0.15), roughness=0.3), Plastic(diffuse=(0.2, 0.5, 0.3), roughness=0.4)]
    torch.manual_seed(0)
    model = SharedNeuBRDF(num_materials=2, nside=8, index_bits=6, hidden=32)
    before = [reflectance_errors(model.material(i), m, n=2 ** 14)["rel_err"] for i, m in enumerate(materials)]
    recipe = replace(recipe_for("shared-neubrdf"), batch_size=1024, lr=1e-2, ema=0.0, lr_decay_every=0)
    result = fit_shared(model, materials, recipe, steps=250, progress=False)
    assert result.steps == 250
    after = [reflectance_errors(model.material(i), m, n=2 ** 14)["rel_err"] for i, m in enumerate(materials)]
    # measured: 0.135 and 0.118 (from 7.7 and 8.3 at initialisation) after 250 joint steps, nside 8
    assert max(after) < 0.25 < min(before), (before, after)
    with pytest.raises(InputError):
        fit_shared(model, materials[:1], recipe, steps=1, progress=False)
    with pytest.raises(InputError):
        JointSource(materials).eval(Query(torch.tensor([[0.0, 0.0, 1.0]]), torch.tensor([[0.0, 0.0, 1.0]])))


def test_fit_clusters_builds_one_shared_model_per_group():
    materials = [Plastic(diffuse=(0.6, 0.3, 0.15)), GGX(roughness=0.2), Plastic(diffuse=(0.2, 0.5, 0.3))]
    clustering = Clustering(labels=np.array([1, 0, 1]), codes=np.zeros((3, 2)), reconstruction_mse=0.0)
    recipe = replace(recipe_for("shared-neubrdf"), batch_size=64, ema=0.0)
    out = fit_clusters(materials, 2, SMALL, recipe, clustering=clustering, steps=2, progress=False)
    assert [group for group, _ in out] == [[1], [0, 2]]
    assert [model.cfg.num_materials for _, model in out] == [1, 2]
    assert all(model.cfg.nside == SMALL["nside"] and not model.training for _, model in out)


def _dense_pair(gen) -> tuple[SharedNeuBRDF, list[NeuBRDF]]:
    """A dense SharedNeuBRDF of 2 materials and, for each, a dense NeuBRDF holding that material's features and
    the same MLP (float64)."""
    shared = SharedNeuBRDF(num_materials=2, features="dense", **SMALL).double()
    with torch.no_grad():
        shared.grid.features.copy_(torch.randn(shared.grid.features.shape, generator=gen, dtype=torch.float64))
    own = []
    for m in range(2):
        ref = NeuBRDF(features="dense", **SMALL).double()
        rows = slice(m * shared.slots_per_material, (m + 1) * shared.slots_per_material)
        with torch.no_grad():
            ref.grid.features.copy_(shared.grid.features[rows])
        ref.mlp.load_state_dict(shared.mlp.state_dict())
        own.append(ref)
    return shared, own


def test_dense_regrid_equals_neubrdfs_regrid_of_each_material(gen):
    """A dense shared model evaluates each material as a NeuBRDF holding its features, before and after
    regridding coarse to fine and back (same interpolant re-sampled per material)."""
    shared, own = _dense_pair(gen)
    q = _queries(300, gen)
    q = Query(q.wi.double(), q.wo.double())
    for nside in (4, 16, 2, None):  # the start, then after each regrid
        with torch.no_grad():
            for m in range(2):
                torch.testing.assert_close(shared.eval_material(m, q), own[m].eval(q), rtol=1e-12, atol=0)
        if nside is not None:
            shared.regrid(nside)
            for ref in own:
                ref.regrid(nside)
    assert shared.cfg.nside == 2 and shared.grid.num_vertices == shared.grid_rows(2) == 2 * own[0].grid_rows(2)
    assert shared.level_i.shape == (2, 12 * 2 * 2)
    fresh = SharedNeuBRDF(num_materials=2, features="dense", **SMALL).double()
    fresh.load_state_dict(shared.state_dict())  # a checkpoint after regridding loads into a fresh model
    assert fresh.cfg.nside == 2
    torch.testing.assert_close(fresh.eval_material(1, q), shared.eval_material(1, q), rtol=0, atol=0)
    shared.prune(0, q.wi[:5], q.wo[:5])
    with pytest.raises(InputError, match="pruned"):
        shared.regrid(4)


def test_quantize_from_dense_builds_one_codebook_from_all_materials(gen):
    """With as many codewords as distinct slot features (spread over both materials, some only in one), the shared
    k-means codebook holds them all and the VQ model evaluates as the dense one; with candidates, each slot's
    K nearest codewords; a checkpoint of the VQ state loads into a fresh dense model."""
    shared, _ = _dense_pair(gen)
    bits = SMALL["index_bits"]
    distinct = torch.randn(2 ** bits, shared.cfg.feature_dim, generator=gen, dtype=torch.float64) * 3
    v = shared.slots_per_material
    pick = torch.cat([torch.randint(0, 2 ** (bits - 1), (v,), generator=gen),  # material 0: the first half only
                      torch.randint(0, 2 ** bits, (v,), generator=gen)])
    pick[v:v + 2 ** bits] = torch.arange(2 ** bits)  # material 1 uses every codeword
    with torch.no_grad():
        shared.grid.features.copy_(distinct[pick])
    q = _queries(300, gen)
    q = Query(q.wi.double(), q.wo.double())
    with torch.no_grad():
        dense = [shared.eval_material(m, q) for m in range(2)]
    shared.quantize_from_dense(candidates=3)
    assert shared.cfg.features == "vq" and shared.grid.candidates.shape == (2 * v, 3)
    shared.train(False)
    with torch.no_grad():
        for m in range(2):
            torch.testing.assert_close(shared.eval_material(m, q), dense[m], rtol=1e-9, atol=1e-12)
    chosen = shared.grid.codebook[shared.grid.indices()]
    torch.testing.assert_close(chosen, distinct[pick], rtol=0, atol=1e-9)
    fresh = SharedNeuBRDF(num_materials=2, features="dense", **SMALL).double()
    fresh.load_state_dict(shared.state_dict())
    assert fresh.cfg.features == "vq"
    fresh.train(False)
    with torch.no_grad():
        torch.testing.assert_close(fresh.eval_material(0, q), dense[0], rtol=1e-9, atol=1e-12)
    with pytest.raises(InputError, match="features='dense'"):
        shared.quantize_from_dense()
    with pytest.raises(InputError, match="candidates"):
        SharedNeuBRDF(num_materials=2, features="dense", **SMALL).quantize_from_dense(candidates=2 ** bits + 1)
    with pytest.raises(InputError, match="features"):
        SharedNeuBRDF(num_materials=2, features="lowbit", **SMALL)


def test_optimizer_updates_only_the_index_logits_of_the_batch(gen):
    """`optimizer`: the VQ logits get sparse row gradients and a step moves only the rows the batch read (at
    index_lr_scale times the rate); a dense model gets a plain Adam over all its parameters."""
    model = SharedNeuBRDF(num_materials=2, **SMALL)
    opt = model.optimizer(1e-2)
    assert [g.get("lr_scale", 1.0) for g in opt.param_groups] == [1.0, model.cfg.index_lr_scale]
    before = model.grid.logits.detach().clone()
    q = _queries(20, gen)
    ids = torch.ones(20, dtype=torch.long)  # material 1 only
    model.eval(MaterialQuery(q.wi, q.wo, material=ids)).sum().backward()
    assert model.grid.logits.grad.is_sparse
    opt.step()
    moved = (model.grid.logits.detach() != before).any(-1)
    assert moved.any() and not moved[:model.slots_per_material].any()  # material 0's rows untouched
    dense = SharedNeuBRDF(num_materials=2, features="dense", **SMALL)
    assert len(dense.optimizer(1e-2).param_groups) == 1


def test_kept_corner_tables_follow_pruning_and_regridding_keeps_the_dtype(gen):
    """The corner tables and the pruned flag, derived from the pruning levels once, are made again when the levels
    change (an evaluation before pruning, then one after, equals a model pruned before any); a float64 model's
    vertex directions stay float64 through a regrid (they became float32, and its lookups with them)."""
    torch.manual_seed(0)
    a, b = SharedNeuBRDF(num_materials=2, **SMALL), SharedNeuBRDF(num_materials=2, **SMALL)
    b.load_state_dict(a.state_dict())
    q, probe, other = _queries(400, gen), _queries(20, gen), _queries(10, gen)
    before = a.eval_material(0, q)
    for m in (a, b):
        m.prune(1, probe.wi, probe.wo)
    pruned_once = a.eval_material(0, q)  # material 0 unpruned yet, its table read
    for m in (a, b):
        m.prune(0, other.wi, other.wo)
    assert torch.equal(pruned_once, before) and not torch.equal(a.eval_material(0, q), before)
    for i in (0, 1):
        torch.testing.assert_close(a.eval_material(i, q), b.eval_material(i, q), rtol=0, atol=0)
    dense = SharedNeuBRDF(num_materials=2, features="dense", **SMALL).double()
    dense.regrid(8)
    assert dense.vertex_dirs.dtype == torch.float64
    own = NeuBRDF(features="dense", **SMALL).double()
    own.regrid(8)
    assert own.vertex_dirs.dtype == torch.float64


@pytest.mark.skipif(cpu_kernels.library() is None, reason=f"CPU kernels unavailable: {cpu_kernels.unavailable()}")
@pytest.mark.parametrize("inputs", ["none", "hd_warp"])
def test_fused_kernel_equals_the_torch_path(gen, inputs):
    """Without autograd the shared model's inverse-distance evaluation is one C call (cpu_kernels.neubrdf_idw_eval):
    equal to the torch path within float32 rounding on random features and MLP, one material pruned (per-material
    corner tables), a MaterialQuery mixing both materials and a plain query on the active one, rows below the
    horizon; a pixel on an edge may fall on the other side (float32 atan2 an ulp apart), so 99.9 % of rows."""
    torch.manual_seed(1)
    m = SharedNeuBRDF(num_materials=2, features="dense", direction_inputs=inputs, **SMALL)
    with torch.no_grad():
        m.grid.features.copy_(torch.randn(m.grid.features.shape, generator=gen))
        for p in m.mlp.parameters():
            p.add_(0.3 * torch.randn(p.shape, generator=gen))
    probe = _queries(20, gen)
    m.prune(1, probe.wi, probe.wo)
    assert m.pruned
    q = _queries(3000, gen)
    wi, wo = q.wi.clone(), q.wo.clone()
    wi[::17, 2] *= -1
    wo[::19, 2] *= -1
    ids = torch.randint(2, (3000,), generator=gen)
    m.select(1)
    for query in (MaterialQuery(wi, wo, material=ids), Query(wi, wo)):
        with torch.no_grad():
            before = cpu_kernels.calls[0]
            fast = m.eval(query)
            assert cpu_kernels.calls[0] == before + 1
            with cpu_kernels.switched_off():
                ref = m.eval(query)
        below = (wi[:, 2] <= 0) | (wo[:, 2] <= 0)
        assert (fast[below] == 0).all() and (ref[~below] > 0).all()
        close = ((fast - ref).abs() <= 1e-5 * ref.abs() + 1e-7).all(-1)
        assert close.float().mean() >= 0.999, float(close.float().mean())
    assert m.eval(Query(wi, wo)).requires_grad  # autograd on: the torch path
