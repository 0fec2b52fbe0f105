"""neumat.nn.cpu_kernels: the fused C kernels against float64 and the torch paths they replace, and their fallback."""
import ctypes
import math
import os
import subprocess
import sys

import pytest
import torch
from torch import nn

from neumat.core.query import Query
from neumat.methods.baselines.nbrdf import NBRDF
from neumat.nn import cpu_kernels
from neumat.nn.mlp import MLP

needs_kernels = pytest.mark.skipif(cpu_kernels.library() is None,
                                   reason=f"CPU kernels unavailable: {cpu_kernels.unavailable()}")


@pytest.fixture
def fresh_kernels(monkeypatch, tmp_path):
    """A library state to change (environment, cache folder), restored after the test."""
    monkeypatch.setenv("NEUMAT_CACHE_DIR", str(tmp_path))
    cpu_kernels.reset()
    yield monkeypatch
    cpu_kernels.reset()


def test_switched_off_by_the_environment(fresh_kernels):
    fresh_kernels.setenv("NEUMAT_CPU_KERNELS", "0")
    assert cpu_kernels.library() is None
    assert "NEUMAT_CPU_KERNELS=0" in cpu_kernels.unavailable()
    assert not cpu_kernels.usable(torch.zeros(2, 3))


def test_without_a_compiler_models_keep_the_torch_path(fresh_kernels):
    fresh_kernels.setenv("CC", "/nonexistent/cc")
    assert cpu_kernels.library() is None
    assert "no C compiler" in cpu_kernels.unavailable()
    model = NBRDF(init_range=0.5)
    wi = torch.tensor([[0.0, 0.0, 1.0]])
    with torch.no_grad():
        assert torch.isfinite(model.eval(Query(wi, wi))).all()


def test_a_failing_compiler_is_named(fresh_kernels):
    fresh_kernels.setenv("CC", "false")
    assert cpu_kernels.library() is None
    assert "false failed" in cpu_kernels.unavailable()


@needs_kernels
@pytest.mark.parametrize("minus_one", [False, True])
def test_exp_and_expm1_within_float32_rounding_of_float64(minus_one):
    x = torch.cat([torch.linspace(-87, 88, 20001), torch.linspace(-1, 1, 20001), torch.logspace(-30, -1, 200),
                   -torch.logspace(-30, -1, 200), torch.tensor([0.0, 0.5, -0.5, 0.49999997, -0.49999997])])
    got = cpu_kernels.exp_values(x, minus_one).double()
    ref = torch.expm1(x.double()) if minus_one else torch.exp(x.double())
    rel = (got - ref).abs() / ref.abs().clamp(min=1e-300)
    assert rel.max() < 4 * 2.0 ** -23, (x[rel.argmax()], got[rel.argmax()], ref[rel.argmax()])


def _random_mlp(in_dim, hidden, layers, out_dim, activation, seed):
    torch.manual_seed(seed)
    mlp = MLP(in_dim, hidden, layers, out_dim, activation)
    with torch.no_grad():
        for lin in mlp.linears():
            lin.weight.uniform_(-1 / math.sqrt(lin.in_features), 1 / math.sqrt(lin.in_features))
            lin.bias.uniform_(-0.5, 0.5)
    return mlp


@needs_kernels
@pytest.mark.parametrize("dims", [(6, 21, 2, 3), (1, 1, 1, 1), (17, 64, 3, 7), (40, 200, 1, 5), (3, 8, 0, 2)])
@pytest.mark.parametrize("activation", ["relu", "leaky_relu", "silu"])
@pytest.mark.parametrize("n", [1, 63, 64, 65, 1000])
def test_mlp_forward_equals_torch(dims, activation, n):
    mlp = _random_mlp(*dims, activation, seed=n)
    x = torch.randn(n, dims[0], generator=torch.Generator().manual_seed(1))
    packed = cpu_kernels.PackedMLP.pack(mlp.net)
    with torch.no_grad():
        torch.testing.assert_close(cpu_kernels.mlp_forward(packed, x), mlp(x), rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("net", [
    MLP(4, 8, 2, 3, "tanh").net,                     # an activation the kernels lack
    MLP(4, 8, 2, 3, "relu", out_activation="exp").net,  # an output activation
    MLP(4, 300, 1, 3, "relu").net,                   # wider than the block buffers
    nn.Sequential(nn.Linear(4, 8), nn.LeakyReLU(0.2), nn.Linear(8, 3)),  # another slope
    nn.Sequential(nn.Linear(4, 8), nn.ReLU(), nn.LeakyReLU(), nn.Linear(8, 3)),  # not Linear / activation pairs
])
def test_chains_the_kernels_do_not_implement_are_refused(net):
    assert cpu_kernels.PackedMLP.pack(net) is None


def _directions(n, seed):
    """Unit directions over the whole sphere (some below the horizon) plus the awkward cases: normal incidence,
    wi = wo, mirror pairs (h at the pole), grazing."""
    g = torch.Generator().manual_seed(seed)
    wi = torch.nn.functional.normalize(torch.randn(n, 3, generator=g), dim=-1)
    wo = torch.nn.functional.normalize(torch.randn(n, 3, generator=g), dim=-1)
    wi[:, 2] = wi[:, 2].abs() * torch.where(torch.rand(n, generator=g) < 0.9, 1.0, -1.0)
    wo[:, 2] = wo[:, 2].abs()
    special = torch.tensor([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8], [0.0, 0.6, 0.8], [1.0, 0.0, 0.0]])
    k = min(len(special), n)
    wi[:k] = special[:k]
    wo[:k] = torch.tensor([[0.0, 0.0, 1.0], [-0.6, 0.0, 0.8], [0.0, 0.6, 0.8], [0.0, 1.0, 1e-3]])[:k]
    return wi, torch.nn.functional.normalize(wo, dim=-1)


@needs_kernels
@pytest.mark.parametrize("config", [{}, {"output": "exp"}, {"half": "theta", "fold_phi_d": True},
                                    {"hidden": 64, "hidden_layers": 3}])
@pytest.mark.parametrize("n", [1, 5, 64, 1000, 20000])
def test_nbrdf_eval_equals_its_torch_path(config, n):
    model = NBRDF(init_range=0.3, **config)
    q = Query(*_directions(n, seed=n))
    with torch.no_grad():
        got = model.eval(q)
        with cpu_kernels.switched_off():
            ref = model.eval(q)
    assert not torch.equal(got, ref) or n < 64  # the kernel ran (its sums are ordered otherwise)
    torch.testing.assert_close(got, ref, rtol=2e-5, atol=1e-6)
    assert (got[q.wi[:, 2] <= 0] == 0).all()


@needs_kernels
@pytest.mark.parametrize("n", [1, 65, 3000])
def test_naive_mlp_eval_equals_its_torch_path(n):
    from neumat.methods.baselines.naive_mlp import NaiveMLP

    torch.manual_seed(n)
    model = NaiveMLP()
    q = Query(*_directions(n, seed=n))
    before = cpu_kernels.calls[0]
    with torch.no_grad():
        got = model.eval(q)
        with cpu_kernels.switched_off():
            ref = model.eval(q)
    assert cpu_kernels.calls[0] > before, "the kernel did not run"
    torch.testing.assert_close(got, ref, rtol=2e-5, atol=1e-6)
    assert (got[(q.wi[:, 2] <= 0) | (q.wo[:, 2] <= 0)] == 0).all()
    out = model.eval(q)  # autograd on: the torch path, gradients reach the weights
    out.sum().backward()
    assert model.mlp.linears()[0].weight.grad is not None


@needs_kernels
def test_nbrdf_eval_split_over_threads_equals_one_thread():
    model = NBRDF(init_range=0.3)
    q = Query(*_directions(3 * cpu_kernels.PARALLEL_ROWS + 7, seed=3))
    threads = torch.get_num_threads()
    with torch.no_grad():
        try:
            torch.set_num_threads(1)
            one = model.eval(q)
            torch.set_num_threads(3)
            three = model.eval(q)
        finally:
            torch.set_num_threads(threads)
    assert torch.equal(one, three)


@needs_kernels
def test_nbrdf_kernel_sees_weight_changes_and_leaves_autograd_to_torch():
    model = NBRDF(init_range=0.3)
    q = Query(*_directions(100, seed=4))
    with torch.no_grad():
        before = model.eval(q)
        model.mlp.linears()[-1].bias.add_(0.5)  # in place: a new version
        after = model.eval(q)
        model.mlp.linears()[-1].bias = nn.Parameter(model.mlp.linears()[-1].bias - 0.5)  # a new tensor
        again = model.eval(q)
    assert not torch.allclose(before, after)
    torch.testing.assert_close(again, before, rtol=1e-6, atol=1e-7)
    out = model.eval(q)  # autograd on: the torch path, gradients reach the weights
    out.sum().backward()
    assert model.mlp.linears()[0].weight.grad is not None


def _sphere_and_edges(n, seed):
    """Unit vectors over the sphere and on HEALPix's edges: the poles, the equator, z = +-2/3 (belt and caps
    meet), x or y = 0 (phi at a quadrant), below the horizon."""
    g = torch.Generator().manual_seed(seed)
    v = torch.nn.functional.normalize(torch.randn(n, 3, generator=g), dim=-1)
    z = torch.tensor([1.0, -1.0, 0.0, 2 / 3, -2 / 3, 0.5, -0.999])
    phi = torch.tensor([0.0, math.pi / 2, math.pi, -math.pi / 2, 0.3, math.pi / 4])
    zz, pp = torch.meshgrid(z, phi, indexing="ij")
    s = torch.sqrt(1 - zz ** 2)
    edges = torch.stack([s * torch.cos(pp), s * torch.sin(pp), zz], -1).reshape(-1, 3)
    return torch.cat([edges, v]).float()


@needs_kernels
@pytest.mark.parametrize("nside", [1, 2, 5, 64, 512])
def test_ring_pixels_equal_healpix_vec2pix(nside):
    from neumat.nn import healpix as hpx

    v = _sphere_and_edges(200000, seed=nside)
    ref = hpx.vec2pix_xyz(nside, *v.t().contiguous())
    got = cpu_kernels.ring_pixels(nside, v)
    differ = int((got != ref.to(torch.int32)).sum())
    # float32 atan2 rounds an ulp apart from torch's now and then, which moves a direction on a pixel edge to the
    # neighbour: 1e-6 of 2M random directions at N_side 64, 1.1e-5 at 512, 8.5e-5 at 4096 (a wrong step: most)
    assert differ <= 1e-4 * len(v), f"{differ} of {len(v)} pixels differ"


@needs_kernels
@pytest.mark.parametrize("nside", [1, 8, 64, 512])
def test_ring_pixels_fast_atan2_path_equals_atan2f_everywhere(nside):
    """The vectorised atan2 with its fallback near pixel edges gives the pixels of atan2f on every row: random
    directions, and directions within 1e-7 of every vertex (where a pixel edge is nearest)."""
    from neumat.nn import healpix as hpx

    verts = hpx.vertex2vec(nside, torch.arange(hpx.nvertices(nside)), torch.float64)
    g = torch.Generator().manual_seed(nside)
    near = verts.repeat(4, 1) + 1e-7 * torch.randn(4 * len(verts), 3, generator=g, dtype=torch.float64)
    v = torch.cat([_sphere_and_edges(500000, seed=nside), torch.nn.functional.normalize(near, dim=-1).float()])
    fast, exact = cpu_kernels.ring_pixels(nside, v), cpu_kernels.ring_pixels(nside, v, exact_atan2=True)
    assert torch.equal(fast, exact), f"{int((fast != exact).sum())} of {len(v)} pixels differ"


def _neubrdf_runtime(seed, **config):
    from neumat.methods.neubrdf.model import NeuBRDF

    torch.manual_seed(seed)
    model = NeuBRDF(**config)
    with torch.no_grad():  # weights far from the paper's init, so that every layer matters
        for p in model.parameters():
            p.add_(0.3 * torch.randn_like(p))
    return model.runtime().eval()


@needs_kernels
@pytest.mark.parametrize("config", [{"nside": 8}, {"nside": 4, "hidden": 20, "hidden_layers": 3},
                                    {"nside": 16, "activation": "relu"}, {"nside": 4, "activation": "silu"},
                                    {"nside": 8, "direction_inputs": "hd"},
                                    {"nside": 8, "direction_inputs": "hd_warp", "features": "dense"}])
@pytest.mark.parametrize("n", [1, 64, 65, 5000])
def test_neubrdf_runtime_eval_equals_its_torch_path(config, n):
    model = _neubrdf_runtime(0, **config)
    q = Query(*_directions(n, seed=n))
    with torch.no_grad():
        assert model._kernel_eval(q.wi, q.wo) is not None, "the kernel does not apply to this runtime model"
        got = model.eval(q)
        with cpu_kernels.switched_off():
            ref = model.eval(q)
    torch.testing.assert_close(got, ref, rtol=2e-5, atol=1e-6)
    assert (got[q.wi[:, 2] <= 0] == 0).all()


def test_neubrdf_kernel_declines_what_it_does_not_implement():
    for config in ({"nside": 4, "runtime_interpolation": "idw"}, {"nside": 4, "activation": "tanh"}):
        model = _neubrdf_runtime(0, **config)
        wi = torch.tensor([[0.0, 0.0, 1.0]])
        with torch.no_grad():
            assert model._kernel_eval(wi, wi) is None, config


def _multiscale_runtime(seed, model_class=None, **config):
    from neumat.methods.latent_mlp.multiscale import MultiScale

    torch.manual_seed(seed)
    model = (model_class or MultiScale)(spatial_size=16, **config)
    with torch.no_grad():  # the frame and warp decoders start at zero weights: give every part a say
        for p in model.parameters():
            p.add_(0.2 * torch.randn_like(p))
    return model.runtime().eval()


def _texture_queries(n, seed, mode):
    g = torch.Generator().manual_seed(seed)
    wi, wo = _directions(n, seed)
    uv = torch.rand(n, 2, generator=g) * 3 - 1  # outside [0, 1) too: the texture tiles
    if mode == "lod":
        return Query(wi, wo, uv=uv, lod=torch.rand(n, generator=g) * 5)
    if mode == "footprint":
        a = torch.randn(n, 2, 2, generator=g) * 0.05
        return Query(wi, wo, uv=uv, footprint=a @ a.transpose(1, 2) + 1e-6 * torch.eye(2))
    return Query(wi, wo, uv=uv)


@needs_kernels
@pytest.mark.parametrize("config", [{}, {"shading_frame": False}, {"radial_warps": False, "hidden_layers": 2},
                                    {"tripleplane": True}])
@pytest.mark.parametrize("mode", ["none", "lod", "footprint"])
@pytest.mark.parametrize("n", [1, 65, 3000])
def test_multiscale_eval_equals_its_torch_path(config, mode, n):
    from neumat.methods.latent_mlp.tripleplane import TriplePlane

    model = _multiscale_runtime(0, TriplePlane) if config.get("tripleplane") else _multiscale_runtime(0, **config)
    q = _texture_queries(n, n, mode)
    with torch.no_grad():
        assert model._kernel_eval(q) is not None, "the kernel does not apply"
        got = model.eval(q)
        with cpu_kernels.switched_off():
            ref = model.eval(q)
    _as_accurate_as_torch(model, q, got, ref)
    assert (got[q.wi[:, 2] <= 0] == 0).all()


def _as_accurate_as_torch(model, q, got, ref):
    """got (the kernel) is about as close to the model's float64 values as the float32 torch path ref is: its median
    relative error within 4x the torch path's (+ 1e-6), its largest within 4x the torch path's or 1e-3. Why not
    row by row, and the floor: near the disk's rim (after the shading frame) the lift z = sqrt(1 - x^2 - y^2)
    amplifies rounding by ~1 / z^2 in both paths, by chance more in one than the other (a row at 1e-4 against
    torch's 1e-5 in a build without FMA); eps / z^2 reaches 1e-3 at z = 0.01, as the GLSL export's test allows at
    grazing angles."""
    import copy

    exact = copy.deepcopy(model).double()
    with torch.no_grad():
        truth = exact.eval(Query(q.wi.double(), q.wo.double(), uv=q.uv.double(),
                                 lod=None if q.lod is None else q.lod.double(),
                                 footprint=None if q.footprint is None else q.footprint.double()))
    scale = truth.abs() + 1e-6
    err_kernel = ((got.double() - truth).abs() / scale).flatten()
    err_torch = ((ref.double() - truth).abs() / scale).flatten()
    assert err_kernel.median() <= 4 * err_torch.median() + 1e-6, (float(err_kernel.median()), float(err_torch.median()))
    assert err_kernel.max() <= max(4 * err_torch.max(), 1e-3), (float(err_kernel.max()), float(err_torch.max()))


@needs_kernels
@pytest.mark.parametrize("mode", ["none", "footprint"])
def test_multiscale_kernel_sees_every_kind_of_parameter_change(mode):
    """What the kernel keeps (packed MLP, textures in its layout, the pyramid's tables) follows the parameters: an
    in-place change, a fused optimiser step (no version bump), a new Parameter assigned, load_state_dict."""
    model = _multiscale_runtime(3)
    twin = _multiscale_runtime(4)
    q = _texture_queries(50, 6, mode)

    def both():
        with torch.no_grad():
            fast = model.eval(q)
            with cpu_kernels.switched_off():
                slow = model.eval(q)
        torch.testing.assert_close(fast, slow, rtol=2e-4, atol=1e-6)
        return fast

    before = both()
    with torch.no_grad():
        model.spatial.raw[0].mul_(0.5)
    changed = both()
    assert not torch.allclose(changed, before)
    model.train()
    opt = model.optimizer(1e-2, (0.9, 0.99), 1e-8)
    model.eval(q).sum().backward()
    opt.step()
    model.eval()
    stepped = both()
    assert not torch.allclose(stepped, changed)
    model.mlp.linears()[-1].bias = nn.Parameter(model.mlp.linears()[-1].bias.detach() + 1.0)
    assert not torch.allclose(both(), stepped)
    model.load_state_dict(twin.state_dict())
    with torch.no_grad():
        torch.testing.assert_close(model.eval(q), twin.eval(q))


def test_multiscale_kernel_declines_what_it_does_not_implement():
    for config in ({"homogeneous": True}, {"spatial_channels": 80, "half_channels": 2, "diff_channels": 2}):
        model = _multiscale_runtime(0, **config)
        q = _texture_queries(4, 0, "none")
        with torch.no_grad():
            assert model._kernel_eval(q) is None, config


@needs_kernels
def test_a_model_evaluated_by_a_kernel_still_copies_and_pickles(tmp_path):
    """The packed weights are kept outside the model: deepcopy (the trainer's EMA) and torch.save still work."""
    import copy

    model = NBRDF(init_range=0.3)
    q = Query(*_directions(70, seed=5))
    with torch.no_grad():
        before = model.eval(q)
        twin = copy.deepcopy(model)
        torch.save(model, tmp_path / "m.pt")
        torch.testing.assert_close(twin.eval(q), before)


def test_a_damaged_cached_library_is_built_again(fresh_kernels):
    """A cached library left damaged (an interrupted write by another process): the next process builds it again.
    In a new process, as it happens: this one has the library loaded, and dlopen would hand back its copy."""
    if cpu_kernels.library() is None:
        pytest.skip(f"CPU kernels unavailable: {cpu_kernels.unavailable()}")
    built = next(cpu_kernels._cache_dir().rglob("*.so"))
    built.unlink()  # a new file under the old name (writing into the loaded one would pull it from under us)
    built.write_bytes(b"not a library")
    code = ("from neumat.nn import cpu_kernels as c; import torch; lib = c.library(); assert lib is not None, "
            "c.unavailable(); print(lib.nbrdf_eval.argtypes is not None)")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                          env={**os.environ, "NEUMAT_CACHE_DIR": str(cpu_kernels._cache_dir().parent)})
    assert done.returncode == 0 and done.stdout.strip() == "True", done.stderr[-2000:]
    assert built.read_bytes()[:4] == b"\x7fELF"


def test_every_kernel_is_declared_from_the_source():
    """The ctypes declarations come from the C source's definitions: every exported kernel, each parameter typed
    (pointers, long, int, float), and a call with a wrong argument type is refused before it reaches C."""
    protos = cpu_kernels.prototypes(cpu_kernels.SOURCE.read_text())
    assert {"nbrdf_eval", "neubrdf_eval", "multiscale_eval", "neumip_eval", "ggx_eval", "dipole_eval",
            "mlp_forward", "ring_pixels_of", "exp_values"} <= set(protos)
    assert protos["ggx_eval"] == ([ctypes.c_void_p, ctypes.c_void_p, ctypes.c_long, ctypes.c_float, ctypes.c_float,
                                   ctypes.c_int, *[ctypes.c_void_p] * 5], ctypes.c_int)
    assert protos["exp_values"] == ([ctypes.c_void_p, ctypes.c_long, ctypes.c_int, ctypes.c_void_p], None)
    with pytest.raises(RuntimeError, match="no ctypes type"):
        cpu_kernels.prototypes("int k(const float *x, double y) {\n")
    lib = cpu_kernels.library()
    if lib is None:
        pytest.skip(f"CPU kernels unavailable: {cpu_kernels.unavailable()}")
    assert all((getattr(lib, name).argtypes, getattr(lib, name).restype) == p for name, p in protos.items())
    x = torch.zeros(1, 3)
    with pytest.raises(ctypes.ArgumentError):  # a float where the row count (long) goes
        lib.ggx_eval(x.data_ptr(), x.data_ptr(), 1.0, 0.1, 0.1, 0, None, None, None, None, x.data_ptr())
    with pytest.raises(TypeError):  # an argument short
        lib.ggx_eval(x.data_ptr(), x.data_ptr(), 1, 0.1, 0.1, 0, None, None, None, None)


def test_on_huge_pages_copies_values_into_memory_aligned_to_a_huge_page():
    import gc
    import mmap

    big = torch.randn(3, 700, 500)  # 4.2 MB
    moved = cpu_kernels.on_huge_pages(big.permute(1, 0, 2))
    assert moved.is_contiguous() and torch.equal(moved, big.permute(1, 0, 2))
    if hasattr(mmap, "MADV_HUGEPAGE"):
        assert moved.data_ptr() % cpu_kernels.HUGE_PAGE == 0
    view = moved[5:7]
    del moved
    gc.collect()  # the tensor keeps its memory map alive
    assert torch.equal(view, big.permute(1, 0, 2)[5:7])
    small = torch.randn(100, 8)
    assert cpu_kernels.on_huge_pages(small).data_ptr() == small.data_ptr()  # under 2 MB: as it was


@needs_kernels
@pytest.mark.parametrize("name", ["multiscale", "neumip-offset"])
@pytest.mark.parametrize("mode", ["none", "lod", "footprint"])
def test_kernels_read_latents_of_a_1k_texture_on_huge_pages_as_torch_does(name, mode):
    """At 1024^2 texels (32 MB a latent: the tables move to huge pages) the kernel still reads what torch reads;
    the footprints there span up to some 100 texels, so rows of one block take from 1 to every probe."""
    from neumat.models.registry import model_class

    torch.manual_seed(0)
    model = model_class(name)(spatial_size=1024)
    with torch.no_grad():
        for p in model.parameters():
            p.add_(0.2 * torch.randn_like(p))
    model = model.runtime().eval()
    q = _texture_queries(3000, 7, mode)
    with torch.no_grad():
        got = model.eval(q)
        with cpu_kernels.switched_off():
            ref = model.eval(q)
    _as_accurate_as_torch(model, q, got, ref)


@needs_kernels
@pytest.mark.parametrize("name", ["neumip", "nbrdf-uv", "neumip-frame", "neumip-offset", "neural-appearance"])
@pytest.mark.parametrize("mode", ["none", "lod", "footprint"])
@pytest.mark.parametrize("n", [1, 65, 3000])
def test_neumip_eval_equals_its_torch_path(name, mode, n):
    from neumat.models.registry import model_class

    model = _multiscale_runtime(0, model_class(name))
    q = _texture_queries(n, n, mode)
    with torch.no_grad():
        assert model._kernel_eval(q) is not None, "the kernel does not apply"
        got = model.eval(q)
        with cpu_kernels.switched_off():
            ref = model.eval(q)
    _as_accurate_as_torch(model, q, got, ref)
    assert (got[q.wi[:, 2] <= 0] == 0).all()


@needs_kernels
@pytest.mark.parametrize("mode", ["none", "lod", "footprint"])
@pytest.mark.parametrize("n", [1, 300])
def test_ggx_mipmap_eval_equals_its_torch_path(mode, n):
    from neumat.methods.latent_mlp.ggx_mipmap import GGXMipmap

    model = _multiscale_runtime(1, GGXMipmap)
    with torch.no_grad():  # rotations of the tangent all round, also on the angle-doubled vector's negative axis
        model.spatial.raw[0][10:12] = torch.randn_like(model.spatial.raw[0][10:12])
        model.spatial.raw[0][10, :2, :] = -1.0
        model.spatial.raw[0][11, :2, :] = 0.0
    q = _texture_queries(n, n + 7, mode)
    with torch.no_grad():
        assert model._kernel_eval(q) is not None, "the kernel does not apply"
        got = model.eval(q)
        with cpu_kernels.switched_off():
            ref = model.eval(q)
    _as_accurate_as_torch(model, q, got, ref)
    assert (got[q.wi[:, 2] <= 0] == 0).all()


def test_neumip_kernel_declines_its_variants():
    from neumat.models.registry import build_model

    for config in ({"type": "neumip", "level_selection": "roulette"}, {"type": "neumip", "spatial_channels": 80}):
        model = build_model({**config, "spatial_size": 16}).runtime().eval()
        with torch.no_grad():
            assert model._kernel_eval(_texture_queries(4, 0, "none")) is None, config


@needs_kernels
def test_threads_work_in_a_forked_child():
    """A child forked after the kernels' thread pool exists (fit-many's and the renderers' worker processes) makes
    a pool of its own (the parent's threads are not in it: with the parent's pool the child's call hung, seen with
    the whole file run at -march=haswell); the call finishes and equals the parent's."""
    import multiprocessing

    model = NBRDF(init_range=0.3)
    q = Query(*_directions(2 * cpu_kernels.PARALLEL_ROWS, seed=6))
    threads = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        with torch.no_grad():
            parent = model.eval(q)  # makes the pool
        ctx = multiprocessing.get_context("fork")
        with ctx.Pool(1) as pool:
            child = pool.apply_async(_eval_in_child, (model, q)).get(timeout=60)
    finally:
        torch.set_num_threads(threads)
    assert torch.equal(child, parent)


def _eval_in_child(model, q):
    torch.set_num_threads(2)
    with torch.no_grad():
        return model.eval(q)


def test_the_kernels_build_where_a_compiler_exists():
    """Where the machine has a C compiler the kernels must build (else every kernel test above skips and a broken
    source would pass unseen); only NEUMAT_CPU_KERNELS=0 or no compiler may leave them out."""
    import os
    import shutil

    if os.environ.get("NEUMAT_CPU_KERNELS", "1") == "0" or shutil.which(os.environ.get("CC") or "cc") is None:
        pytest.skip("no C compiler here, or the kernels switched off: nothing to build")
    assert cpu_kernels.library() is not None, cpu_kernels.unavailable()


@needs_kernels
@pytest.mark.parametrize("spec", ["ggx:roughness=0.2", "ggx:alpha_x=0.05,alpha_y=0.4,fresnel=dielectric,eta=1.5",
                                  "ggx:roughness=0.01,fresnel=schlick,f0=0.5", "ggx:roughness=0.6,fresnel=none",
                                  "ggx:roughness=0.3,material=gold"])
def test_analytic_ggx_kernel_is_as_accurate_as_torch(spec):
    """Against the float64 torch formulas: the kernel's relative error within 2x the float32 torch path's, median
    and largest; 0 below the horizon."""
    from neumat.catalog.open_material import open_material

    m = open_material(spec)
    wi, wo = _directions(5000, seed=11)
    q = Query(wi, wo)
    with torch.no_grad():
        got = m.eval(q)
        with cpu_kernels.switched_off():
            ref = m.eval(q)
            truth = m.eval(Query(wi.double(), wo.double()))
    scale = truth.abs() + 1e-6
    err_kernel, err_torch = (got.double() - truth).abs() / scale, (ref.double() - truth).abs() / scale
    assert err_kernel.median() <= 2 * err_torch.median() + 1e-7
    assert err_kernel.max() <= 2 * err_torch.max() + 1e-7
    assert (got[(wi[:, 2] <= 0) | (wo[:, 2] <= 0)] == 0).all()


def _svbrdf_source(seed=3):
    """A principled SVBRDF of random 12 x 20 maps: tilted normals (one along +u, where the tangent degenerates),
    roughness down to 0 (the alpha floor), metalness over [0, 1]."""
    from neumat.io.texture_set import TextureSet
    from neumat.reflectance.svbrdf import SVBRDF

    g = torch.Generator().manual_seed(seed)
    h, w = 12, 20
    normal = torch.nn.functional.normalize(torch.randn(h, w, 3, generator=g) * torch.tensor([0.5, 0.5, 1.0])
                                           + torch.tensor([0.0, 0.0, 1.0]), dim=-1)
    normal[0, 0] = torch.tensor([1.0, 0.0, 0.0])
    roughness = torch.rand(h, w, generator=g)
    roughness[1, :5] = 0.0
    return SVBRDF(TextureSet(color=torch.rand(h, w, 3, generator=g), normal=normal, roughness=roughness,
                             metalness=(torch.rand(h, w, generator=g) > 0.5).float() * torch.rand(h, w, generator=g),
                             height=torch.zeros(h, w)), samples=7)


@needs_kernels
@pytest.mark.parametrize("symmetrise", [True, False])
def test_svbrdf_point_value_is_as_accurate_as_torch(symmetrise):
    """The principled SVBRDF's point value by the kernel against the float64 torch formulas, at uv beyond [0, 1)
    (tiling): its relative error within 4x the float32 torch path's (median, and largest or 1e-3: bilinear texel
    coordinates amplify uv's rounding as the latent kernels' do); 0 wherever a direction is below the horizon."""
    src = _svbrdf_source()
    wi, wo = _directions(5003, seed=12)
    uv = torch.rand(5003, 2, generator=torch.Generator().manual_seed(4)) * 4 - 1.5
    with torch.no_grad():
        got = src.eval_point(wi, wo, uv, symmetrise)
        with cpu_kernels.switched_off():
            ref = src.eval_point(wi, wo, uv, symmetrise)
            truth = src.eval_point(wi.double(), wo.double(), uv.double(), symmetrise)
    scale = truth.abs() + 1e-6
    err_kernel, err_torch = (got.double() - truth).abs() / scale, (ref.double() - truth).abs() / scale
    assert err_kernel.median() <= 4 * err_torch.median() + 1e-6, (float(err_kernel.median()), float(err_torch.median()))
    assert err_kernel.max() <= max(4 * err_torch.max(), 1e-3), (float(err_kernel.max()), float(err_torch.max()))
    assert (got[(wi[:, 2] <= 0) | (wo[:, 2] <= 0)] == 0).all() and float(got.abs().sum()) > 0


@needs_kernels
@pytest.mark.parametrize("footprint", [False, True])
def test_svbrdf_filtered_value_by_the_kernel_equals_the_torch_path(footprint):
    """A footprint's mean (7 positions a query, lod or anisotropic footprints, 2051 queries: not a multiple of the
    kernel's block) from the same positions (the generator reseeded) as the torch path's, within float32 rounding of
    the sum; the kernel is used (the torch point evaluation is never called)."""
    src = _svbrdf_source()
    n = 2051
    g = torch.Generator().manual_seed(8)
    wi, wo = _directions(n, seed=13)
    uv = torch.rand(n, 2, generator=g)
    if footprint:
        a = torch.randn(n, 2, 2, generator=g) * 0.05
        q = Query(wi, wo, uv=uv, footprint=a @ a.transpose(1, 2) + 1e-6 * torch.eye(2))
    else:
        q = Query(wi, wo, uv=uv, lod=torch.rand(n, generator=g) * 4)
    with torch.no_grad():
        src.generator.manual_seed(5)
        torch_path = src.eval_point
        src.eval_point = None  # the filtered kernel path must not fall back to it
        got = src.eval(q)
        src.eval_point = torch_path
        with cpu_kernels.switched_off():
            src.generator.manual_seed(5)
            ref = src.eval(q)
    assert torch.allclose(got, ref, rtol=1e-5, atol=1e-6 * float(ref.abs().max())), float((got - ref).abs().max())
    assert float(ref.abs().sum()) > 0


@needs_kernels
@pytest.mark.parametrize("nside", [1, 2, 3, 5, 8, 64])
def test_healpix_corner_vertices_equal_the_torch_path(nside):
    """Every ring pixel's corner vertex ids by the kernel equal the int64 torch path's, bit for bit: at level 0 (any
    nside), and for a power of two at every ancestor level, one for all pixels and one per pixel."""
    from neumat.nn import healpix as hpx

    pix = torch.arange(12 * nside * nside)
    levels = [0]
    if nside & (nside - 1) == 0:
        levels += list(range(1, nside.bit_length())) + [torch.randint(0, nside.bit_length(), (len(pix),),
                                                                     generator=torch.Generator().manual_seed(1))]
    for level in levels:
        got = hpx._corner_vertices(nside, pix, level)
        with cpu_kernels.switched_off():
            ref = hpx._corner_vertices(nside, pix, level)
        assert got.dtype == torch.int64 and torch.equal(got, ref), level
