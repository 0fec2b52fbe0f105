"""Conformance of every registered model, looping over the registry: it declares what the trainer and `neumat list`
use, answers the Material protocol (shape, finiteness, the horizon, the input's dtype), trains two steps through
the command line's path, round-trips a `.nmat` file bit for bit, and passes the chi-square test where it samples.
The same checks run on a GPU against the CPU (marker `cuda`). A method's small config is its `Method.small`."""
from __future__ import annotations

import copy
import dataclasses
from dataclasses import replace

import numpy as np
import pytest
import torch
from PIL import Image
from typer.testing import CliRunner

from btf_util import synthetic_btf
from neumat.cli.main import app
from neumat.core.query import Query
from neumat.fit.method import recipe_config_for_source, recipe_for, recipe_names
from neumat.fit.trainer import fit
from neumat.fit.translucent_observations import Observations
from neumat.io.btf import write_btf
from neumat.io.modelfile import read_model_file
from neumat.catalog.modelfile import load_model, save_model
from neumat.catalog.open_material import open_material
from neumat.models.base import SOURCE_KINDS, LearnedMaterial
from neumat.models.registry import load_all
from neumat.fit.method import load_methods
from neumat.testing.chi2 import chi2_material
from neumat.warp.hemisphere import sample_cosine_hemisphere
from neumat.warp.sphere import sample_uniform_sphere

NAMES = load_all().names()
METHODS = load_methods()


def _model(name: str, dtype=torch.float32) -> LearnedMaterial:
    torch.manual_seed(0)
    method = METHODS.get(name)
    model = method.model(**method.small)
    if method.prepare is not None:
        method.prepare(model)
    return model.to(dtype)


def _queries(model, n: int = 512, dtype=torch.float32, device="cpu") -> Query:
    """Queries on the model's domain (whole sphere, or the hemisphere with 1/8 below the horizon), uv and x
    where the model reads them."""
    g = torch.Generator().manual_seed(7)
    u = torch.rand(n, 6, generator=g, dtype=torch.float64)
    if model.full_sphere:
        wi, wo = sample_uniform_sphere(u[:, :2]), sample_uniform_sphere(u[:, 2:4])
        x = 0.5 * sample_uniform_sphere(u[:, 4:6])
    else:
        wi, wo, x = sample_cosine_hemisphere(u[:, :2]), sample_cosine_hemisphere(u[:, 2:4]), None
        wi[: n // 8, 2] *= -1
    uv = u[:, 4:6] if model.spatially_varying else None
    n_ = None if x is None else 2 * x  # the normal of the sphere of radius 0.5 at x
    cast = lambda t: None if t is None else t.to(device, dtype)  # noqa: E731
    return Query(cast(wi), cast(wo), uv=cast(uv), x=cast(x), n=cast(n_))


def test_every_model_is_a_method():
    # every model has a method (its recipes); the one more is the proxy sampler attached to any material (not a
    # saved model)
    assert set(recipe_names()) - set(NAMES) == {"proxy-sampler"} and set(NAMES) <= set(recipe_names())
    assert all(METHODS.get(name).model is load_all().get(name) for name in NAMES)


@pytest.mark.parametrize("name", NAMES)
def test_model_declares_what_the_trainer_and_list_use(name):
    cls = load_all().get(name)
    assert issubclass(cls, LearnedMaterial) and cls.name == name
    assert cls.paper and set(cls.source_kinds) <= set(SOURCE_KINDS)
    assert dataclasses.is_dataclass(cls.Config)
    recipe = recipe_for(name)
    assert recipe.steps > 0 and recipe.batch_size > 0
    model = _model(name)
    assert model.size_bytes() == model.size_bytes("fp16") > 0 and model.flops() >= 0


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_eval_shape_finite_horizon_and_dtype(name, dtype):
    model = _model(name, dtype)
    q = _queries(model, dtype=dtype)
    with torch.no_grad():
        f = model.eval(q)
    assert f.shape == (len(q), 3) and f.dtype == dtype
    assert bool(torch.isfinite(f).all())
    if not model.full_sphere:
        below = (q.wi[:, 2] <= 0) | (q.wo[:, 2] <= 0)
        assert below.any() and bool((f[below] == 0).all())


@pytest.mark.parametrize("name", NAMES)
def test_eval_on_slices_of_rows_equals_one_call(name):
    """A model whose eval works on slices of `eval_chunk` rows (issue 49: flat cost per query up to 2^20) gives
    what one call over all rows gives, up to rounding (a short slice runs the vector kernels' scalar tails)."""
    model = _model(name, torch.float64).train(False)
    q = _queries(model, dtype=torch.float64)
    with torch.no_grad():
        whole = model.eval(q)
        model.eval_chunk = 37  # 512 rows: 14 slices, the last one shorter
        sliced = model.eval(q)
    torch.testing.assert_close(sliced, whole, rtol=1e-12, atol=1e-14)


def _texture_set(folder):
    folder.mkdir()
    rng = np.random.default_rng(0)
    Image.fromarray(rng.integers(0, 256, (16, 16, 3), dtype=np.uint8)).save(folder / "T_Color.png")
    Image.fromarray(rng.integers(60, 200, (16, 16), dtype=np.uint8)).save(folder / "T_Roughness.png")
    normal = np.concatenate([rng.integers(100, 156, (16, 16, 2)), np.full((16, 16, 1), 240)], -1)
    Image.fromarray(normal.astype(np.uint8)).save(folder / "T_NormalGL.png")
    return folder


def _observations(path):
    g = torch.Generator().manual_seed(3)
    n = 256
    x = torch.nn.functional.normalize(torch.randn(n, 3, generator=g), dim=-1)
    wo = sample_uniform_sphere(torch.rand(n, 2, generator=g))
    wi = sample_uniform_sphere(torch.rand(n, 2, generator=g))
    value = 0.1 + 0.05 * torch.rand(n, 3, generator=g)
    Observations(x=x, n=x.clone(), wo=wo, wi=wi, value=value).save(path)
    return path


def _sources(kind: str, tmp_path) -> list[str]:
    """Command-line SOURCE arguments of a small source of `kind`."""
    if kind == "brdf":
        return ["ggx:roughness=0.3"]
    if kind == "brdf-set":
        return ["ggx:roughness=0.3", "lambert"]
    if kind == "svbrdf":
        return [str(_texture_set(tmp_path / "set"))]
    if kind == "btf":
        return [str(write_btf(tmp_path / "b.nbtf", synthetic_btf(0, size=10)))]
    if kind == "translucent":
        return [str(_observations(tmp_path / "obs.npz"))]
    raise AssertionError(f"no test source for kind {kind!r}")


def _set_args(name: str) -> list[str]:
    args = []
    for k, v in METHODS.get(name).small.items():
        args += ["--set", f"{k}={','.join(map(str, v)) if isinstance(v, list) else v}"]
    return args + ["--set", f"batch_size={64}"]


@pytest.mark.parametrize("name", NAMES)
def test_two_step_fit_through_the_command_line(name, tmp_path):
    kind = load_all().get(name).source_kinds[0]
    out = tmp_path / "m.nmat"
    res = CliRunner().invoke(app, ["fit", *_sources(kind, tmp_path), "--model", name, "--steps", "2", "-q",
                                   "--device", "cpu", *_set_args(name), "-o", str(out)])
    assert res.exit_code == 0, res.output
    model = load_model(out)
    assert model.name == name
    # what `fit` writes is the shipped form: its tensors take at most twice the reported fp16 bytes (float32
    # weights), plus what size_bytes leaves out by design and only matters at these tiny sizes (Fourier
    # matrices regenerated from a seed, direction tables, the dipole's surface quadrature): at most 4 KB
    stored = sum(t.numel() * t.element_size() for t in read_model_file(out)[1].values())
    assert stored <= 2 * model.size_bytes("fp16") + 4096, (stored, model.size_bytes("fp16"))
    with torch.no_grad():
        assert bool(torch.isfinite(model.eval(_queries(model))).all())


@pytest.mark.parametrize("name", NAMES)
def test_nmat_round_trip_is_bit_identical(name, tmp_path):
    model = _model(name)
    with torch.no_grad():
        for p in model.parameters():  # not the initial values: they may be constants
            p.add_(0.01 * torch.randn(p.shape, generator=torch.Generator().manual_seed(p.numel())))
    first = save_model(model, tmp_path / "a.nmat")
    loaded = load_model(first)
    state, again = model.state_dict(), loaded.state_dict()
    assert state.keys() == again.keys() and all(torch.equal(state[k], again[k]) for k in state)
    assert save_model(loaded, tmp_path / "b.nmat").read_bytes() == first.read_bytes()
    q = _queries(model)
    with torch.no_grad():
        assert torch.equal(model.eval(q), loaded.eval(q))



@pytest.mark.parametrize("name", NAMES)
def test_the_module_itself_pickles(name, tmp_path):
    """`torch.save` of the module (what multiprocessing and users' own checkpoints do), not only its state: it
    loads back and evaluates bit for bit (a lambda among its hooks made NeuBRDF's fail)."""
    model = _model(name)
    torch.save(model, tmp_path / "model.pt")
    loaded = torch.load(tmp_path / "model.pt", weights_only=False)
    q = _queries(model)
    with torch.no_grad():
        assert torch.equal(model.eval(q), loaded.eval(q))

def _python_source(kind: str, args: list[str]):
    """The in-process source of `kind` that the command-line arguments `args` (from `_sources`) name."""
    if kind == "translucent":
        return Observations.load(args[0])
    opened = [open_material(a) for a in args]
    return opened if kind == "brdf-set" else opened[0]


class Interrupt(Exception):
    pass


#: sparse-btf without a given dictionary trains one on the BTF it codes, and says so
pytestmark = pytest.mark.filterwarnings("ignore:sparse-btf. no option 'dictionary' given")


@pytest.mark.parametrize("name", NAMES)
def test_checkpoint_written_mid_run_resumes_to_the_uninterrupted_result(name, tmp_path):
    """Every model, multi-phase ones included (neural-appearance, neupress, sparse-btf: a checkpoint inside the
    first phase): 4 steps uninterrupted, against 2 steps, a checkpoint, and a resumed run (a one-step solver:
    its finished checkpoint resumes without changing the model)."""
    kind = load_all().get(name).source_kinds[0]
    args = _sources(kind, tmp_path)
    recipe = replace(recipe_for(name), steps=4, batch_size=64, log_every=1, checkpoint_every=1)
    derived = recipe_config_for_source(name, _python_source(kind, args), recipe.options)

    def run(**kw):
        torch.manual_seed(0)
        model = load_all().get(name)(**{**derived, **METHODS.get(name).small})
        return model, fit(model, _python_source(kind, args), recipe, progress=False, device="cpu", **kw)

    ref_model, ref = run()
    ckpt = tmp_path / "fit.ckpt"
    if ref.steps > 2:
        def stop(record):
            if record["step"] == 2:
                raise Interrupt

        with pytest.raises(Interrupt):
            run(checkpoint=ckpt, callback=stop)
    else:
        run(checkpoint=ckpt)
    model, res = run(checkpoint=ckpt, resume=True)
    ref_state, state = ref_model.state_dict(), model.state_dict()
    assert ref_state.keys() == state.keys() and all(torch.equal(ref_state[k], state[k]) for k in ref_state)
    strip = lambda h: [{k: v for k, v in r.items() if k != "seconds"} for r in h]  # noqa: E731
    assert strip(res.history) == strip(ref.history)


SAMPLERS = [n for n in NAMES if load_all().get(n).can_sample]


@pytest.mark.parametrize("name", SAMPLERS)
def test_sampler_chi_square(name):
    model = _model(name).eval()
    wi = torch.nn.functional.normalize(torch.tensor([0.3, -0.2, 0.8]), dim=0)
    template = _queries(model, n=1)
    # over the whole sphere: a BRDF sampler may send glossy samples below the horizon (with their pdf)
    result = chi2_material(model, wi, n_samples=200_000, res=(40, 40), template=template, sphere=True)
    assert result.passed, result


def _proxy_sampled() -> LearnedMaterial:
    """A model that cannot sample with the proxy sampler attached (`neumat.methods.neural_appearance.proxy_sampler`)."""
    from neumat.methods.neural_appearance.proxy_sampler import ProxySampler, SampledMaterial
    torch.manual_seed(0)
    return SampledMaterial(_model("naive-mlp"), ProxySampler())


@pytest.mark.parametrize("name", SAMPLERS + ["proxy-sampler"])
def test_sample_weight_contract(name):
    """Sample.weight = f(wi, wo) cos(theta_o) / pdf, finite, with pdf the model's own pdf(wo), and 0 where sampling
    failed (pdf 0), on queries with some incident directions below the horizon."""
    model = (_proxy_sampled() if name == "proxy-sampler" else _model(name)).eval()
    q = _queries(model, n=2048)
    u = torch.rand(len(q), 2, generator=torch.Generator().manual_seed(3))
    with torch.no_grad():
        s = model.sample(q, u)
        at = Query(q.wi, s.wo, uv=q.uv, x=q.x, n=q.n)
        f, pdf = model.eval(at), model.pdf(at)
    assert s.wo.shape == (len(q), 3) and s.pdf.shape == (len(q),) and s.weight.shape == (len(q), 3)
    assert bool(torch.isfinite(s.weight).all() and torch.isfinite(s.pdf).all() and (s.pdf >= 0).all())
    ok = s.pdf > 0
    assert 0.5 < float(ok.float().mean()) and bool((s.weight[~ok] == 0).all())  # most draws sampled
    torch.testing.assert_close(s.pdf[ok], pdf[ok], rtol=1e-4, atol=1e-6)
    expected = f[ok] * s.wo[ok, 2:].clamp(min=0) / s.pdf[ok, None]
    torch.testing.assert_close(s.weight[ok], expected, rtol=1e-4, atol=1e-6)
    assert float(expected.abs().max()) > 0  # not vacuously all zero


@pytest.mark.cuda
@pytest.mark.parametrize("name", NAMES)
def test_cuda_eval_matches_cpu(name):
    model = _model(name)
    q = _queries(model)
    with torch.no_grad():
        cpu = model.eval(q)
        gpu = model.to("cuda").eval(q.to("cuda"))
    assert gpu.device.type == "cuda"
    torch.testing.assert_close(gpu.cpu(), cpu, rtol=1e-4, atol=1e-6)


@pytest.mark.cuda
@pytest.mark.parametrize("name", NAMES)
def test_cuda_two_step_fit(name, tmp_path):
    kind = load_all().get(name).source_kinds[0]
    res = CliRunner().invoke(app, ["fit", *_sources(kind, tmp_path), "--model", name, "--steps", "2", "-q",
                                   "--device", "cuda", *_set_args(name), "-o", str(tmp_path / "m.nmat")])
    assert res.exit_code == 0, res.output


def _drjit_names() -> list[str]:
    from neumat.export.drjit.format import drjit_models
    return drjit_models()


@pytest.mark.mitsuba
@pytest.mark.parametrize("compute", ["fp32", "fp16"])
@pytest.mark.parametrize("name", _drjit_names())
def test_drjit_coopvec_form_matches_torch(name, compute):
    """The Dr.Jit runtime's cooperative-vector MLP (the form CUDA runs, here on LLVM) against the torch model: every
    hidden activation has to exist on cooperative vectors (SiLU once did not, so 7 models failed on the GPU only);
    fp16 within its rounding (a 10-bit mantissa through a few layers)."""
    from mitsuba_util import mitsuba_or_skip
    mitsuba_or_skip()
    from neumat.export.drjit.format import export_drjit
    from neumat.export.drjit.runtime import load_runtime
    from neumat.testing.drjit_parity import drjit_eval
    model = _model(name).runtime().eval()
    q = _queries(model)
    with torch.no_grad():
        ours = model.eval(q).double()
        ref = copy.deepcopy(model).double().eval(_queries(model, dtype=torch.float64))
    scale = float(ref.abs().max())
    assert scale > 0, "a model that is zero everywhere tests nothing"
    got = drjit_eval(load_runtime(export_drjit(model, precision="fp32").source(), "llvm", compute, "coopvec"), q)
    err = float((got.double() - ref).abs().max()) / scale
    torch_err = float((ours - ref).abs().max()) / scale  # float32 rounding, amplified by an exp output
    assert err < (2 * torch_err + 1e-6 if compute == "fp32" else 2e-2), (err, torch_err)
