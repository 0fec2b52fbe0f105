"""NeuPreSS: Fourier features, skip connections, eval / sampling shapes and checks, fitting the appearance
module to a known function, and the sampler recovering a known lobe width."""
import math

import pytest
import torch

from neumat import InputError
from neumat.core.query import Query
from neumat.testing.kernel_parity import kernel_and_torch_errors
from neumat.methods.neupress.targets import light_grid, neupress_predict, sampler_kl
from neumat.fit.method import recipe_for
from neumat.fit.trainer import fit
from neumat.fit.translucent_fit import best_validation, observation_mse
from neumat.fit.translucent_observations import Observations
from neumat.methods.neupress.model import NeuPreSS
from neumat.models.registry import build_model
from neumat.nn import cpu_kernels
from neumat.nn.fourier import FourierFeatures
from neumat.nn.skip_mlp import SkipMLP
from neumat.testing.chi2 import chi2_directions
from neumat.warp import azimuthal_gaussian_pdf, sample_uniform_sphere

SMALL = dict(features=32, width=32, layers=3, sampler_hidden=(32, 16))


def _sphere_points(n, seed=0):
    g = torch.Generator().manual_seed(seed)
    return sample_uniform_sphere(torch.rand(n, 2, generator=g))


def test_fourier_features_closed_form():
    ff = FourierFeatures(3, 8, mean=18.0, std=1.0, seed=4)
    v = torch.rand(5, 3)
    a = 2 * math.pi * v.double() @ ff.G.double().T  # arguments up to ~400 rad: float32 keeps ~4e-5 of them
    assert torch.allclose(ff(v).double(), torch.cat([torch.cos(a), torch.sin(a)], -1), atol=3e-4)
    assert ff.G.shape == (8, 3) and float(ff.G.min()) > 10  # mean 18, std 1: a positive matrix
    assert torch.equal(FourierFeatures(3, 8, seed=4).G, ff.G) and "G" in ff.state_dict()
    with pytest.raises(InputError, match="last dimension"):
        ff(torch.rand(5, 2))


def test_skip_mlp_adds_the_input_of_every_pair():
    net = SkipMLP(4, 6, 4, 2)  # first layer, one skip pair, one plain layer
    v = torch.randn(7, 4)
    h = torch.relu(net.first(v))
    h = torch.relu(h + net.hidden[1](torch.relu(net.hidden[0](h))))
    h = torch.relu(net.hidden[2](h))
    assert torch.allclose(net(v), net.out(h))
    assert net.flops() == 2 * (4 * 6 + 3 * 36 + 6 * 2) + 6


def test_skip_mlp_without_skips_is_the_plain_mlp_of_the_same_layers():
    net = SkipMLP(4, 6, 4, 2, skips=False)
    v = torch.randn(7, 4)
    h = torch.relu(net.first(v))
    h = torch.relu(net.hidden[1](torch.relu(net.hidden[0](h))))
    h = torch.relu(net.hidden[2](h))
    assert torch.allclose(net(v), net.out(h))
    with_skips = SkipMLP(4, 6, 4, 2)
    with_skips.load_state_dict(net.state_dict())  # the same parameters: only the additions differ
    assert not torch.allclose(with_skips(v), net(v))
    assert net.flops() == 2 * (4 * 6 + 3 * 36 + 6 * 2) and net.num_parameters() == with_skips.num_parameters()
    m = NeuPreSS(features=8, width=8, layers=3, skips=False)
    assert m.appearance.skips is False
    with pytest.raises(InputError, match="skips"):
        NeuPreSS(skips="no")


def test_registered_eval_shapes_and_checks():
    m = build_model({"type": "neupress", **SMALL})
    assert isinstance(m, NeuPreSS) and m.full_sphere and not m.can_sample
    x = _sphere_points(10)
    q = Query(wi=_sphere_points(10, 1), wo=x.clone(), x=x, n=x.clone())
    f = m.eval(q)
    assert f.shape == (10, 3) and bool((f >= 0).all())
    with pytest.raises(InputError, match="Query.x"):
        m.eval(Query(wi=q.wi, wo=q.wo))
    with pytest.raises(InputError, match="Query.n"):
        m.sample_incident(Query(wi=q.wi, wo=q.wo, x=x), torch.rand(10, 2))
    with pytest.raises(InputError, match="direction_encoding"):
        NeuPreSS(direction_encoding="polar")
    with pytest.raises(InputError, match="layers"):
        NeuPreSS(layers=0)
    assert m.size_bytes("fp32") > m.size_bytes("fp16") > 0


def _synthetic(n, seed=0):
    """Observations of a smooth translucent-like function on the unit sphere: light through the object
    (1 + wi . x) and a view lobe, coloured by position."""
    x = _sphere_points(n, seed)
    wi, wo = _sphere_points(n, seed + 1), x.clone()
    value = (0.5 + 0.5 * (wi * x).sum(-1, keepdim=True)) * (0.6 + 0.4 * x.abs()) * wo[:, 2:].abs()
    return Observations(x=x, n=x.clone(), wo=wo, wi=wi, value=value)


def test_appearance_fit_reaches_a_known_function():
    torch.manual_seed(0)
    train, test = _synthetic(20000), _synthetic(2000, seed=7)
    m = NeuPreSS(features=64, width=64, layers=3, feature_mean=0.0, feature_std=0.5)  # measured: 0.6% of var
    history = fit(m, train, _recipe(400, batch_size=1024, lr=3e-3, validation_fraction=0), progress=False).history
    assert [r["phase"] for r in history] == ["appearance"] * 4
    with torch.no_grad():
        mse = ((m.raw(test.wi, test.x, test.wo) - test.value) ** 2).mean()
    assert history[-1]["mse"] < history[0]["mse"]
    assert float(mse) < 0.02 * float(test.value.var()), (float(mse), float(test.value.var()))


def test_the_recipe_loss_is_what_the_observation_fit_descends(monkeypatch):
    """recipe.loss names the step's loss: a recording loss registered for the test is called on every step with the
    batch's predictions and values, and its value is the record ("l2" logs it as "mse", another loss by its name);
    "l2" is the mean squared error."""
    from neumat.fit.losses import LOSSES, L2Loss

    calls = []

    class Recording(L2Loss):
        def forward(self, pred, target, q):
            calls.append((pred.shape, target.shape, q))
            return 3 * super().forward(pred, target, q)

    monkeypatch.setitem(LOSSES._items, "recording", Recording)
    data = _synthetic(512)
    torch.manual_seed(0)
    history = fit(NeuPreSS(**SMALL), data, _recipe(3, batch_size=64, loss="recording", log_every=1,
                                                   validation_fraction=0), progress=False).history
    assert calls == [(torch.Size([64, 3]), torch.Size([64, 3]), None)] * 3
    assert all(r["recording"] == r["loss"] for r in history), history[0]  # the record's own and its total
    torch.manual_seed(0)
    history_l2 = fit(NeuPreSS(**SMALL), data, _recipe(3, batch_size=64, loss="l2", log_every=1,
                                                      validation_fraction=0), progress=False).history
    assert history[0]["loss"] == pytest.approx(3 * history_l2[0]["mse"], rel=1e-5)  # same batch, same weights


def _recipe(appearance, sampler=0, **changes):
    """NeuPreSS's recipe with `appearance` + `sampler` steps and `changes` (recipe fields or options)."""
    r = recipe_for("neupress")
    r.steps = appearance + sampler
    r.phase_split = (appearance / r.steps, sampler / r.steps)
    for k, v in changes.items():
        if k in r.options:
            r.options[k] = v
        else:
            setattr(r, k, v)
    return r


class _Lobe(NeuPreSS):
    """A NeuPreSS whose appearance is exactly the azimuthal Gaussian of width SIGMA around the normal at x
    (x on the unit sphere, so the normal is x)."""

    SIGMA = 0.6

    def raw(self, wi, x, wo):
        return azimuthal_gaussian_pdf(wi, x, torch.full_like(wi[:, 0], self.SIGMA))[:, None].expand(-1, 3)


def test_sampler_kl_recovers_the_lobe_width():
    torch.manual_seed(0)
    m = _Lobe(**SMALL)
    obs = _synthetic(512)
    grid = light_grid(32, 64)
    # the sampler phase alone (no appearance steps; _Lobe's appearance is fixed)
    fit(m, obs, _recipe(0, 150, sampler_batch=16, lr=3e-3, validation_fraction=0), progress=False)
    with torch.no_grad():
        sigma = m.sigma(obs.x, obs.wo)
        # a per-point network on a flat optimum: the median is tight, single points scatter a few percent
        assert abs(float(sigma.median()) / _Lobe.SIGMA - 1) < 0.02, float(sigma.median())
        assert torch.allclose(sigma, torch.full_like(sigma, _Lobe.SIGMA), rtol=0.1), sigma.aminmax()
        # the KL at the right width is at most the one at a width 30% off
        at = sampler_kl(m, obs.x[:16], obs.wo[:16], obs.n[:16], grid)
        m.sampler[-1].bias.add_(math.log(1.3))
        assert float(at) < float(sampler_kl(m, obs.x[:16], obs.wo[:16], obs.n[:16], grid))


def test_sampler_kl_is_the_same_whatever_rows_its_target_takes_at_once(monkeypatch):
    """The frozen appearance module's target is evaluated in chunks of TARGET_ROWS rows: chunks that do not divide
    the points x bins give the one-call value (float32 rounding apart)."""
    from neumat.methods.neupress import targets
    torch.manual_seed(0)
    m = NeuPreSS(**SMALL)
    obs = _synthetic(64)
    grid = light_grid(8, 16)
    with torch.no_grad():
        monkeypatch.setattr(targets, "TARGET_ROWS", 10 ** 6)
        whole = sampler_kl(m, obs.x[:7], obs.wo[:7], obs.n[:7], grid)
        monkeypatch.setattr(targets, "TARGET_ROWS", 100)  # 7 x 128 rows: 9 chunks, the last of 96
        torch.testing.assert_close(sampler_kl(m, obs.x[:7], obs.wo[:7], obs.n[:7], grid), whole, rtol=1e-5, atol=0)
    assert float(whole) > 0


def test_light_grid_covers_the_sphere():
    w, area = light_grid(32, 64, dtype=torch.float64)
    assert w.shape == (2048, 3) and abs(float(area.sum()) - 4 * math.pi) < 1e-12
    assert torch.allclose(w.norm(dim=-1), torch.ones(2048, dtype=torch.float64))


def test_sample_incident_chi2_and_pdf_agree():
    """The light directions `sample_incident` draws follow `incident_pdf` (sigma about 0.4 at a tilted
    normal: at this width the antipodal spike of the lobe holds no measurable mass for the world grid)."""
    torch.manual_seed(1)
    m = NeuPreSS(**SMALL)
    with torch.no_grad():
        m.sampler[-1].bias.fill_(math.log(0.4))
        m.sampler[-1].weight.mul_(0.01)
    x = torch.nn.functional.normalize(torch.tensor([[0.3, -0.2, 0.9]]), dim=-1)

    def query(n, wi=None):
        xs = x.expand(n, 3)
        return Query(wi=xs if wi is None else wi, wo=xs, x=xs, n=xs)

    def sample_fn(u):
        wi, pdf = m.sample_incident(query(len(u)), u.float())
        return wi, pdf > 0

    with torch.no_grad():
        result = chi2_directions(sample_fn, lambda w: m.incident_pdf(query(len(w), w.float())), sphere=True,
                                 n_samples=300_000)
    assert result.passed, result


def test_incident_lobe_is_what_sample_incident_and_incident_pdf_use():
    torch.manual_seed(2)
    m = NeuPreSS(**SMALL)
    g = torch.Generator().manual_seed(0)
    x = torch.nn.functional.normalize(torch.randn(64, 3, generator=g), dim=-1)
    wo = torch.nn.functional.normalize(torch.randn(64, 3, generator=g), dim=-1)
    u = torch.rand(64, 2, generator=g)
    q = Query(wi=x, wo=wo, x=x, n=x)
    with torch.no_grad():
        lobe = m.incident_lobe(q)
        wi, pdf = m.sample_incident(q, u)
        assert torch.equal(lobe.sigma, m.sigma(x, wo)) and torch.equal(lobe.axis, x)
        assert torch.equal(lobe.sample(u)[0], wi) and torch.equal(lobe.sample(u)[1], pdf)
        assert torch.equal(lobe.pdf(wi), m.incident_pdf(Query(wi=wi, wo=wo, x=x, n=x)))
    with pytest.raises(InputError, match="needs Query.n"):
        m.incident_lobe(Query(wi=x, wo=wo, x=x))


def test_validation_keeps_the_weights_that_generalise_best():
    """Heavy-tailed noise (a few samples carry most of the value, as in path-traced targets) on 3000 points:
    without a validation set the network learns the noise by heart; with one it ends at the record of
    lowest validation error, which is also closer to the clean function."""
    torch.manual_seed(0)
    clean, test = _synthetic(4000, seed=3), _synthetic(2000, seed=7)
    g = torch.Generator().manual_seed(5)
    spikes = (torch.rand(len(clean), 1, generator=g) < 0.1).float() * 10.0  # mean 1, relative std 3
    noisy = Observations(clean.x, clean.n, clean.wo, clean.wi, clean.value * spikes)
    train, validation = noisy.split(0.25, seed=1)  # what the validated fit holds back (recipe seed 1)

    def clean_mse(model):
        with torch.no_grad():
            return float(((model.raw(test.wi, test.x, test.wo) - test.value) ** 2).mean())

    results = {}
    for name, source, fraction in (("plain", train, 0), ("validated", noisy, 0.25)):
        torch.manual_seed(0)
        m = NeuPreSS(features=64, width=64, layers=3, feature_mean=0.0, feature_std=2.0)
        recipe = _recipe(600, batch_size=512, lr=3e-3, log_every=25, validation_fraction=fraction, seed=1)
        history = fit(m, source, recipe, progress=False).history
        results[name] = clean_mse(m)
    # the validation MSE after every record of the history (every 25 steps)
    assert [r["step"] for r in history] == list(range(25, 601, 25))
    assert all("validation_mse" in r for r in history)
    best = min(r["validation_mse"] for r in history)
    assert best_validation(history)["validation_mse"] == best
    assert observation_mse(neupress_predict(m), validation) == pytest.approx(best, rel=1e-6)
    assert history[-1]["validation_mse"] > best  # it did overfit by the end: the restore mattered
    assert results["validated"] < 0.7 * results["plain"], results
    with pytest.raises(InputError, match="validation"):
        fit(m, train, _recipe(1, validation_fraction=1.0), progress=False)
    with pytest.raises(InputError, match="diverged"):  # Adam steps of 1e30 overflow float32
        fit(m, train, _recipe(2, lr=1e30, log_every=1, validation_fraction=0.25), progress=False)


def test_source_must_be_observations():
    m = NeuPreSS(**SMALL)
    with pytest.raises(InputError, match="Observations"):
        fit(m, build_model({"type": "naive-mlp"}), _recipe(2), progress=False)


@pytest.mark.skipif(cpu_kernels.library() is None, reason=f"CPU kernels unavailable: {cpu_kernels.unavailable()}")
@pytest.mark.parametrize("config", [{}, {"feature_mean": 18.0, "feature_std": 1.0},
                                    {"direction_encoding": "cartesian", "skips": False, "layers": 6}])
def test_small_batches_run_the_row_kernel_as_close_to_float64_as_torch(config):
    """Batches up to cpu_kernels.NEUPRESS_ROWS without autograd run `neupress_rows` (one row at a time), larger ones
    and autograd torch: the kernel's worst error relative to its row, against the model in float64, within 2x the
    float32 torch path's over ten batches (the default and the paper's Fourier scale, the Cartesian plain variant)."""
    torch.manual_seed(0)
    m = NeuPreSS(width=64, features=64, **config)
    with torch.no_grad():
        for p in m.appearance.parameters():
            p.add_(0.05 * torch.randn_like(p))
    m.set_bounds(torch.tensor([-0.6, -0.5, -0.55]), torch.tensor([0.6, 0.5, 0.55]))
    g = torch.Generator().manual_seed(1)
    kernel = torch32 = 0.0
    for _ in range(10):
        n = cpu_kernels.NEUPRESS_ROWS
        q = Query(sample_uniform_sphere(torch.rand(n, 2, generator=g)),
                  sample_uniform_sphere(torch.rand(n, 2, generator=g)), x=torch.rand(n, 3, generator=g) - 0.5)
        _, k, t = kernel_and_torch_errors(m, q, Query(q.wi.double(), q.wo.double(), x=q.x.double()), floor=1e-6)
        kernel, torch32 = max(kernel, k), max(torch32, t)
    assert kernel <= 2 * torch32, (kernel, torch32)
    assert m.eval(q).requires_grad  # autograd on: torch, with gradients
    larger = Query(*(torch.cat([t, t]) for t in (q.wi, q.wo)), x=torch.cat([q.x, q.x]))
    with torch.no_grad():
        before = cpu_kernels.calls[0]
        m.eval(larger)
        assert cpu_kernels.calls[0] == before  # past NEUPRESS_ROWS: torch's sgemm
