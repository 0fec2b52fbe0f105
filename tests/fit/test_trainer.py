"""The trainer: a NeuBRDF fit reaches a stated error, resume equals an uninterrupted run, EMA against a hand
computation, hooks, and clear errors on bad sources and names."""
from __future__ import annotations

import math

import pytest
import torch
from torch import nn

from neumat.core.errors import DataFormatError, InputError, UnknownNameError
from neumat.core.material import Material, upper_hemisphere
from neumat.core.query import Query
from neumat.fit.query_samplers import QUERY_SAMPLERS
from neumat.fit.recipe import Recipe
from neumat.fit.trainer import fit
from neumat.models.base import LearnedMaterial
from neumat.methods.neubrdf.model import NeuBRDF
from neumat.warp.hemisphere import sample_cosine_hemisphere


class Blinn(Material):
    """Lambert + normalised Blinn-Phong lobe (exponent 20), closed form in the query's dtype."""

    name = "blinn"

    def eval(self, q: Query) -> torch.Tensor:
        h = q.wi + q.wo
        h = h / h.norm(dim=-1, keepdim=True)
        kd = torch.tensor([0.6, 0.4, 0.2], dtype=q.dtype, device=q.device)
        ks = torch.tensor([0.3, 0.3, 0.35], dtype=q.dtype, device=q.device)
        f = kd / math.pi + ks * (22 / (2 * math.pi)) * h[:, 2:3].clamp(min=0) ** 20
        return torch.where(upper_hemisphere(q.wi, q.wo).unsqueeze(-1), f, torch.zeros_like(f))


class Constant(LearnedMaterial):
    """A learnable constant BRDF exp(p) (3 parameters), recording the hook calls it receives."""

    name = "constant"

    def __init__(self) -> None:
        super().__init__()
        self.p = nn.Parameter(torch.tensor([-1.0, 0.0, 0.5]))
        self.calls: list[tuple[int, int]] = []

    def eval(self, q: Query) -> torch.Tensor:
        return torch.exp(self.p).expand(len(q), 3)

    def on_step(self, step: int, total: int) -> None:
        self.calls.append((step, total))


def _test_queries(n: int = 20000) -> Query:
    g = torch.Generator().manual_seed(99)
    return Query(sample_cosine_hemisphere(torch.rand(n, 2, generator=g)),
                 sample_cosine_hemisphere(torch.rand(n, 2, generator=g)))


@pytest.mark.parametrize("features, bound", [("vq", 0.28), ("dense", 0.10)])
def test_neubrdf_fit_reaches_error(features, bound):
    """300 steps of 4096 cosine-weighted queries, log_cos loss, lr 0.03, EMA 0.05; NeuBRDF N_side 8, b 6,
    MLP 2 x 32, on a Lambert + Blinn-Phong lobe. Relative L2 error on held-out cosine-weighted queries,
    measured (seeds fixed, one thread): vq 0.238, dense 0.072; a constant (the mean) scores 0.69. (With
    the earlier ReLU MLP, default output initialisation and index logits at the base learning rate: vq
    0.238, dense 0.074; ReLU collapsed on dark measured materials, see `neumat.methods.neubrdf.train`.)
    Each fit takes about 6 s on one core."""
    torch.manual_seed(0)
    m = NeuBRDF(nside=8, index_bits=6, hidden=32, features=features)
    recipe = Recipe(steps=300, batch_size=4096, lr=0.03, ema=0.05, log_every=100)
    result = fit(m, Blinn(), recipe, progress=False)
    assert result.model is m and not m.training and result.steps == 300
    assert [r["step"] for r in result.history] == [100, 200, 300]
    assert result.history[-1]["loss"] < result.history[0]["loss"]
    q = _test_queries()
    y = Blinn().eval(q.to(dtype=torch.float64))
    with torch.no_grad():
        err = ((m.eval(q).double() - y).norm() / y.norm()).item()
    const = ((y.mean(0) - y).norm() / y.norm()).item()
    assert const > 0.65
    assert err < bound, err


def _small_fit(checkpoint=None, resume=False, callback=None, steps=None):
    torch.manual_seed(3)
    m = NeuBRDF(nside=2, index_bits=3, hidden=8)
    recipe = Recipe(steps=12, batch_size=64, lr=0.02, ema=0.2, lr_decay=0.5, lr_decay_every=5, log_every=3,
                    checkpoint_every=6, grad_clip=1.0)
    return m, fit(m, Blinn(), recipe, progress=False, checkpoint=checkpoint, resume=resume, callback=callback,
                  steps=steps)


def test_resume_equals_uninterrupted_run(tmp_path):
    ref_model, ref = _small_fit()

    class Interrupt(Exception):
        pass

    def stop_at_6(record):
        if record["step"] == 6:
            raise Interrupt

    ckpt = tmp_path / "fit.ckpt"
    with pytest.raises(Interrupt):
        _small_fit(checkpoint=ckpt, callback=stop_at_6)
    blob = torch.load(ckpt, weights_only=True)
    assert blob["step"] == 6 and blob["cpu_seconds"] > 0
    model, res = _small_fit(checkpoint=ckpt, resume=True)
    assert ref.cpu_seconds > 0 and res.cpu_seconds > blob["cpu_seconds"]  # the cut run's CPU seconds carried over
    ref_state, state = ref_model.state_dict(), model.state_dict()
    assert ref_state.keys() == state.keys()
    for k in ref_state:
        assert torch.equal(ref_state[k], state[k]), k
    strip = lambda h: [{k: v for k, v in r.items() if k != "seconds"} for r in h]  # noqa: E731
    assert strip(res.history) == strip(ref.history) and len(res.history) == 4
    # a finished checkpoint resumes to the same result without training further
    again, res2 = _small_fit(checkpoint=ckpt, resume=True)
    assert all(torch.equal(again.state_dict()[k], state[k]) for k in state)
    blob = torch.load(ckpt, weights_only=True)  # one written before CPU seconds were recorded: unknown
    del blob["cpu_seconds"]
    torch.save(blob, ckpt)
    assert _small_fit(checkpoint=ckpt, resume=True)[1].cpu_seconds is None


def test_resume_with_other_recipe_or_bad_file_raises(tmp_path):
    ckpt = tmp_path / "fit.ckpt"
    _small_fit(checkpoint=ckpt)
    with pytest.raises(InputError, match="different recipe.*steps"):
        _small_fit(checkpoint=ckpt, resume=True, steps=20)
    ckpt.write_bytes(b"not a checkpoint")
    with pytest.raises(DataFormatError, match="checkpoint"):
        _small_fit(checkpoint=ckpt, resume=True)
    with pytest.raises(InputError, match="checkpoint path"):
        _small_fit(resume=True)


def _constant_fit(ema: float) -> tuple[Constant, list[torch.Tensor]]:
    """Fit a Constant; returns it and the parameters it had at each draw of queries before a step (the first
    draw is the initialisation's; the trainer's end-of-fit check draws once more, after the last step)."""
    m = Constant()
    seen = []

    def queries(n, generator, device):  # called once per step, before that step's update
        seen.append(m.p.detach().clone())
        return QUERY_SAMPLERS.get("cosine")(Blinn())(n, generator, device)

    fit(m, Blinn(), Recipe(steps=7, batch_size=32, lr=0.1, ema=ema, loss="l2"), progress=False, queries=queries)
    assert len(seen) == 9
    return m, seen[:8]


def test_ema_matches_hand_computation():
    raw_model, raw_seen = _constant_fit(ema=0.0)
    ema_model, ema_seen = _constant_fit(ema=0.3)
    assert all(torch.equal(a, b) for a, b in zip(raw_seen, ema_seen))  # the EMA leaves the raw trajectory alone
    after = raw_seen[1:] + [raw_model.p.detach()]  # parameters after steps 0 .. 6
    shadow = raw_seen[0].double()
    for p in after:
        shadow = 0.7 * shadow + 0.3 * p.double()
    torch.testing.assert_close(ema_model.p.detach().double(), shadow, rtol=1e-6, atol=1e-7)
    assert not torch.allclose(shadow, after[-1].double(), atol=1e-3)  # the EMA really differs from the last step


def test_on_step_hook_and_schedule():
    m = Constant()
    lrs = []
    recipe = Recipe(steps=6, batch_size=8, lr=0.1, lr_decay=0.5, lr_decay_every=2, log_every=1, ema=0.5)
    res = fit(m, Blinn(), recipe, progress=False, callback=lambda r: lrs.append(r["lr"]))
    assert m.calls == [(s, 6) for s in range(6)]
    assert lrs == [0.1, 0.1, 0.05, 0.05, 0.025, 0.025] == [r["lr"] for r in res.history]


def test_model_optimizer_and_lr_scale_of_its_groups():
    """A model's `optimizer` hook is used; a param group's "lr_scale" multiplies the schedule's rate."""
    m = NeuBRDF(nside=2, index_bits=2, hidden=4)
    made = []
    hook = m.optimizer
    m.optimizer = lambda *a: made.append(hook(*a)) or made[-1]
    fit(m, Blinn(), Recipe(steps=3, batch_size=16, lr=0.01, lr_decay=0.5, lr_decay_every=2), progress=False)
    (opt,) = made
    assert [g["lr"] for g in opt.param_groups] == [0.005, 0.005 * m.cfg.index_lr_scale]
    assert opt.param_groups[1]["params"] == [m.grid.logits] and m.cfg.index_lr_scale == 10.0


def test_progress_bar_and_default_recipe(monkeypatch):
    """Without a recipe the default preset's is used (here shortened through `steps` and a smaller batch)."""
    from neumat.methods.neubrdf import train as neubrdf_recipe
    monkeypatch.setattr(neubrdf_recipe.CPU_RECIPE, "batch_size", 16)
    m = NeuBRDF(nside=2, index_bits=3, hidden=4, features="dense", direction_inputs="hd_warp")
    res = fit(m, Blinn(), steps=3, progress=True)
    assert res.steps == 3 and res.recipe.batch_size == 16 and res.history[-1]["step"] == 3


class _NaNSource(Material):
    name = "broken source"

    def eval(self, q: Query) -> torch.Tensor:
        f = torch.ones(len(q), 3)
        f[0, 1] = float("nan")
        return f


class _SpatialSource(Blinn):
    name = "textured"
    spatially_varying = True


class _SphereSource(Blinn):
    name = "translucent"
    full_sphere = True


@pytest.mark.parametrize("source, match", [
    (_NaNSource(), "broken source.*non-finite"),
    (_SpatialSource(), "textured.*spatially varying"),
    (_SphereSource(), "translucent.*whole sphere"),
    ("ggx:roughness=0.2", "must be a Material"),
])
def test_bad_source_raises(source, match):
    m = NeuBRDF(nside=2, index_bits=2, hidden=4)
    with pytest.raises(InputError, match=match):
        fit(m, source, Recipe(steps=2, batch_size=8, lr=0.01), progress=False)


def test_textured_model_gets_uv_from_spatial_source():
    m = NeuBRDF(nside=2, index_bits=2, hidden=4, texture_height=4, texture_width=4, texture_channels=2)
    res = fit(m, _SpatialSource(), Recipe(steps=2, batch_size=8, lr=0.01, log_every=1), progress=False)
    assert len(res.history) == 2


@pytest.mark.parametrize("kwargs, error, match", [
    (dict(loss="l3"), UnknownNameError, "unknown loss 'l3'.*l1"),
    (dict(queries="cosin"), UnknownNameError, "did you mean cosine"),
    (dict(steps=-1), InputError, "Recipe.steps"),
])
def test_bad_names_and_values_raise(kwargs, error, match):
    m = NeuBRDF(nside=2, index_bits=2, hidden=4)
    with pytest.raises(error, match=match):
        fit(m, Blinn(), Recipe(steps=2, batch_size=8, lr=0.01), progress=False, **kwargs)


def test_model_without_recipe_or_parameters_raises():
    with pytest.raises(UnknownNameError, match="no training recipe for model 'constant'"):
        fit(Constant(), Blinn(), progress=False)
    frozen = Constant().requires_grad_(False)
    with pytest.raises(InputError, match="no trainable parameters"):
        fit(frozen, Blinn(), Recipe(steps=1, batch_size=4, lr=0.1), progress=False)
    with pytest.raises(InputError, match="nn.Module"):
        fit(Blinn(), Blinn(), Recipe(steps=1, batch_size=4, lr=0.1), progress=False)


class _Drifting(NeuBRDF):
    """A NeuBRDF whose output is scaled up step after step (no gradient through the scale): its loss rises, as a
    fit that blows up does."""

    def on_step(self, step: int, total_steps: int) -> None:
        self.scale = 1.0 + step

    def eval(self, q):
        return super().eval(q) * getattr(self, "scale", 1.0)


def test_a_fit_that_ends_far_above_its_best_loss_says_so():
    """The trainer's check at the end of each phase: the last record far above the phase's lowest is a FitWarning
    and in FitResult.warnings; a fit that improves stays silent."""
    from neumat.fit.trainer import ENDS_ABOVE_BEST, FitWarning, ended_above_best

    recipe = Recipe(steps=40, batch_size=64, lr=1e-3, log_every=5)
    with pytest.warns(FitWarning, match=r"phase 'fit' ended at loss .*x its lowest .* at step 5; medians of the"):
        res = fit(_Drifting(nside=2, index_bits=2, hidden=4), Blinn(), recipe, progress=False)
    medians = [r["loss_median"] for r in res.history]
    # the output 40x its fit also reflects more light than it receives: that check speaks too
    assert [w.split(": ")[1][:20] for w in res.warnings] == ["phase 'fit' ended at", "the fitted model ref"]
    assert medians[-1] > ENDS_ABOVE_BEST * min(medians)
    history = [{"phase": "a", "step": 1, "loss": 1.0}, {"phase": "a", "step": 2, "loss": 1.9},
               {"phase": "b", "step": 3, "loss": 5.0}, {"phase": "b", "step": 4, "loss": 0.1}]
    assert ended_above_best(history, "m") == []


def _records(losses, phase="fit", start=0, every=50):
    return [{"phase": phase, "step": start + every * (i + 1), "loss": v} for i, v in enumerate(losses)]


def test_the_end_of_a_fit_is_compared_with_its_lowest_record_after_the_warm_up():
    """Issue 55: the first records of a phase (its first WARMUP_FRACTION of steps) average the loss of a model near
    its initialisation, which a relative loss can score far below a sound fit's end; they are not its "lowest".
    A blow-up after the warm-up still warns, in every phase from that phase's own start."""
    from neumat.fit.trainer import WARMUP_FRACTION, ended_above_best

    assert WARMUP_FRACTION * 1000 >= 50
    # neumip-frame, robust loss, polished Metal027 crop (1000 steps, a record every 50): a transient, then a descent
    transient = [1.305, 7.146, 7.956, 13.155, 9.042, 12.691, 7.997, 10.532, 8.609, 9.902, 8.588, 9.202, 7.863,
                 6.858, 5.984, 4.697, 3.93, 3.574, 3.099, 2.687]
    assert ended_above_best(_records(transient), "m") == []
    # a blow-up: lowest at step 900, the end 4.5x above it
    blowup = [40.0, 30.0, 25.0, 20.0, 18.0, 15.0, 14.0, 12.0, 11.0, 10.0, 9.0, 8.5, 8.0, 7.5, 7.0, 6.5, 6.2, 5.78,
              12.0, 26.1]
    (text,) = ended_above_best(_records(blowup), "m")
    assert "ended at loss 26.1, 4.5x its lowest (5.78 at step 900;" in text
    # a low first record does not hide a later blow-up: compared with the lowest after the warm-up
    (text,) = ended_above_best(_records([0.5, 3.0, 2.0, 1.0, 1.0, 1.0, 1.2, 1.5, 2.5, 9.0]), "m")
    assert "ended at loss 9, 9.0x its lowest (1 at step 200;" in text
    # phases: the second one's warm-up counts from its own start (step 1000), not from 0
    two = _records(blowup) + _records(transient, phase="refine", start=1000)
    (text,) = ended_above_best(two, "m")
    assert "phase 'fit' ended at loss 26.1" in text


def test_records_keep_the_median_step_loss_and_the_end_check_reads_it():
    """Issue 55: on a near-mirror one batch in a record's window can lift its mean loss 2.3x above the fit's lowest
    while the fit is at its best (the polished plate at 8000 steps); each record keeps the median of its steps'
    losses, which the end-of-fit check compares. Checked against the same fit recorded at every step."""
    from neumat.fit.trainer import ended_above_best

    def run(every):
        torch.manual_seed(0)
        m = NeuBRDF(nside=2, index_bits=2, hidden=4)
        return fit(m, Blinn(), Recipe(steps=20, batch_size=64, lr=1e-2, log_every=every), progress=False).history

    per_step, windows = run(1), run(5)
    losses = torch.tensor([r["loss"] for r in per_step], dtype=torch.float64)
    for k, r in enumerate(windows):
        window = losses[5 * k: 5 * k + 5]
        assert r["loss_median"] == pytest.approx(window.median().item(), rel=1e-6)
        assert r["loss"] == pytest.approx(window.mean().item(), rel=1e-5)
    # one heavy step in the last window: its mean 2.3x the lowest, its median level -> silent
    heavy = [dict(r, loss_median=m) for r, m in zip(_records([1.0, 0.5, 0.4, 0.3, 0.2, 0.16, 0.14, 0.13, 0.12, 0.28]),
                                                       [1.0, 0.5, 0.4, 0.3, 0.2, 0.15, 0.13, 0.12, 0.11, 0.12])]
    assert ended_above_best(heavy, "m") == []
    # every step of the last window high: its median too -> warns
    heavy[-1]["loss_median"] = 0.25
    (text,) = ended_above_best(heavy, "m")
    assert "ended at loss 0.25, 2.3x its lowest (0.11 at step 450;" in text


def test_a_loss_spike_that_stalls_the_fit_says_so():
    """Issue 55: neumip-frame on a Metal027 crop spiked from 1.6 to 2.3e5 at step 200 and stalled near 2.0 (NeuMIP
    reaches 0.03) without ending above its lowest; a record SPIKE times the lowest before it in its phase warns,
    naming the step and the fix; the transient of a sound fit and a spike in another phase's start do not."""
    from neumat.fit.trainer import SPIKE, ended_above_best, loss_spikes

    stalled = [0.915, 2.999, 1.633, 231105.46, 3.208, 2.423, 2.284, 2.138, 2.104, 2.055, 2.056, 2.072, 1.953, 1.99,
               2.037, 2.001, 1.969, 1.941, 1.977, 1.985]
    assert ended_above_best(_records(stalled), "m") == []
    (text,) = loss_spikes(_records(stalled), "m")
    assert "phase 'fit' spiked to loss 2.311e+05 at step 200, 2.53e+05x its lowest before (0.915)" in text
    assert "recipe.grad_clip=1" in text
    (clipped,) = loss_spikes(_records(stalled), "m", grad_clip=1.0)
    assert "grad_clip" not in clipped.split("try ")[1].split(";")[0] and "clipped at norm 1)" in clipped
    transient = [1.305, 7.146, 7.956, 13.155, 9.042, 12.691, 7.997, 10.532, 8.609, 9.902, 8.588, 9.202, 7.863]
    assert loss_spikes(_records(transient), "m") == []
    phases = _records([1e-6, 1e-6]) + _records([SPIKE * 2e-6, 1.0], phase="refine", start=100)
    assert loss_spikes(phases, "m") == []
    assert loss_spikes(_records([1.0, float("nan"), 0.0, SPIKE * 1.01]), "m")[0].startswith("fit m: phase 'fit' spiked")


class _Dead(NeuBRDF):
    """A NeuBRDF whose output is 1e-30 of what its network computes: a network that died (every unit inactive)."""

    def eval(self, q):
        return super().eval(q) * 1e-30


class _Flat(Material):
    """A source without variation: the same value for every query."""

    name = "flat"

    def eval(self, q: Query) -> torch.Tensor:
        return torch.full((len(q), 3), 0.2, dtype=q.dtype, device=q.device)


def test_a_fit_whose_output_collapsed_says_so():
    """A network that dies early (neural-appearance at lr 1e-2 on Metal027: output 1e-27 of the source's) ends with
    its loss flat at its lowest, which neither loss check sees; the end-of-fit check on held-out queries does:
    near zero, or near constant while the source varies. Sound fits, and a source without variation, stay silent."""
    from neumat.fit.trainer import COLLAPSED, FitWarning

    recipe = Recipe(steps=30, batch_size=64, lr=1e-2, log_every=5)
    with pytest.warns(FitWarning, match=r"output is near zero \(mean \|output\| .* against the source's .*, at 4096 "
                                        r"of the fit's queries\); after a full recipe this is a network that "
                                        r"died early"):
        res = fit(_Dead(nside=2, index_bits=2, hidden=4), Blinn(), recipe, progress=False)
    assert len(res.warnings) == 1
    with pytest.warns(FitWarning, match=r"output is near constant \(its spread over the queries at most 0x"):
        fit(Constant(), Blinn(), recipe, progress=False)
    torch.manual_seed(0)
    sound = fit(NeuBRDF(nside=2, index_bits=2, hidden=4), Blinn(), recipe, progress=False)
    assert not [w for w in sound.warnings if "learned none" in w]  # (30 steps: its albedo is Blinn's + 10 %)
    assert not [w for w in fit(Constant(), _Flat(), recipe, progress=False).warnings if "learned none" in w]
    # the bounds, with models that are the source scaled: by a factor (size), or about its mean (spread)
    for size, spread, warns in [(2 * COLLAPSED, 1.0, None), (COLLAPSED / 2, 1.0, "near zero"),
                                (1.0, 2 * COLLAPSED, None), (1.0, COLLAPSED / 2, "near constant")]:
        res = fit(_Scaled(size, spread), Blinn(), Recipe(steps=1, batch_size=8, lr=1e-3), progress=False)
        assert [warns in w for w in res.warnings] == ([True] if warns else [])


class _Scaled(LearnedMaterial):
    """`source`'s value (Blinn's by default) scaled by `size`, its variation about a level of 0.1 by `spread` (at
    spread 1 exactly `size` times the source; one idle parameter)."""

    name = "scaled"

    def __init__(self, size: float, spread: float = 1.0, source: Material | None = None) -> None:
        super().__init__()
        self.size, self.spread, self.idle = size, spread, nn.Parameter(torch.zeros(()))
        self.source = Blinn() if source is None else source

    def eval(self, q: Query) -> torch.Tensor:
        return self.size * (self.spread * self.source.eval(q) + (1 - self.spread) * 0.1) + 0 * self.idle


class _Lambert(Material):
    """A Lambertian source of directional albedo `albedo` (over 1: a source that itself gains energy)."""

    name = "lambert"

    def __init__(self, albedo: float) -> None:
        self.albedo = albedo

    def eval(self, q: Query) -> torch.Tensor:
        return torch.full((len(q), 3), self.albedo / math.pi, dtype=q.dtype, device=q.device)


class _Lobe(LearnedMaterial):
    """`gain` times an energy-conserving Phong lobe about the mirror direction (albedo at most 0.95 at every
    incidence; at exponent 2000 a polished metal, whose cosine-weighted albedo estimates are heavy-tailed)."""

    name = "lobe"

    def __init__(self, gain: float = 1.0, exponent: int = 2000) -> None:
        super().__init__()
        self.gain, self.exponent, self.idle = gain, exponent, nn.Parameter(torch.zeros(()))

    def eval(self, q: Query) -> torch.Tensor:
        mirror = q.wi * torch.tensor([-1.0, -1.0, 1.0], dtype=q.dtype)
        n = self.exponent
        lobe = (mirror * q.wo).sum(-1).clamp(min=0) ** n * ((n + 2) / (2 * math.pi)) / q.wo[:, 2].clamp(min=1e-3)
        return (self.gain * 0.95 * lobe).unsqueeze(-1).expand(len(q), 3) + 0 * self.idle


def _energy(model, source, queries: str | None = None) -> list[str]:
    from neumat.fit.phase import FitContext
    from neumat.fit.trainer import energy_gain

    recipe = Recipe(steps=1, batch_size=8, lr=1e-3, queries=queries or "cosine")
    return energy_gain(FitContext(model, source, recipe, torch.device("cpu"), torch.Generator()))


def test_a_fit_that_reflects_more_light_than_it_receives_says_so():
    """The end-of-fit energy check: a fitted BRDF whose directional albedo exceeds 1, and the source's where that
    is more, by ENERGY_MARGIN beyond its noise (the neubrdf suite's replay fits of clear-coated RGL files reach 5
    to 20 at 80 degrees against the files' 0.2-0.3; their losses show nothing). Lambertian models have exact
    estimates (f pi at every sample), so the bounds are checked to the margin; a sharp, physical lobe, whose
    estimates are heavy-tailed, stays silent (the check is blind to a gain confined to such a lobe: a handful of its
    2048 directions fall in it); sparse measurements get their own advice."""
    from neumat.fit.measured_samples import MeasuredSamples
    from neumat.fit.trainer import ENERGY_MARGIN, FitWarning

    half = _Lambert(0.5)
    assert _energy(_Scaled(source=half, size=1.0), half) == []
    assert _energy(_Scaled(source=half, size=2.0), half) == []  # albedo 1.0: at the bound
    (text,) = _energy(_Scaled(source=half, size=3.0), half)
    assert text == ("fit scaled: the fitted model reflects more light than it receives: directional albedo 1.5 "
                    "(channel 0) at normal incidence (at most 1 for a physical BRDF; the source's 0.5); the fit "
                    "overshoots where its queries are few: try more steps (--set recipe.steps=...) or another seed")
    bright = _Lambert(1.2)  # a source over 1 (measured noise): the model is held to the source's albedo
    assert _energy(_Scaled(source=bright, size=1.0), bright) == []
    assert _energy(_Scaled(source=bright, size=1 + 0.8 * ENERGY_MARGIN / 1.2), bright) == []
    assert "albedo 1.26 " in _energy(_Scaled(source=bright, size=1 + 1.2 * ENERGY_MARGIN / 1.2), bright)[0]
    assert _energy(_Lobe(), _Lobe()) == [] and _energy(_Lobe(1.5), _Lobe()) == []
    assert _energy(_Lobe(exponent=50), _Lobe(exponent=50)) == []
    (text,) = _energy(_Lobe(1.5, exponent=50), _Lobe(exponent=50))  # the same directions: their ratio is exact
    model_albedo, source_albedo = (float(text.split(k)[1].split(" ")[0].rstrip(");")) for k in ("albedo ", "source's "))
    assert model_albedo / source_albedo == pytest.approx(1.5, rel=0.01)
    # sparse measurements: no albedo of their own (the bound is 1), and the advice to measure or balance
    g = torch.Generator().manual_seed(0)
    q = Query(sample_cosine_hemisphere(torch.rand(512, 2, generator=g)),
              sample_cosine_hemisphere(torch.rand(512, 2, generator=g)))
    samples = MeasuredSamples.from_material(half, q)
    (text,) = _energy(_Scaled(source=half, size=3.0), samples, "replay")
    assert text.endswith("(at most 1 for a physical BRDF); where the measurements are few (far from the specular "
                         "peak, at grazing angles) the fit is unconstrained, and renders too bright there: measure "
                         "more directions, or draw the measurements balanced over directions "
                         "(--set queries=replay_cells)")
    assert _energy(_Scaled(source=half, size=3.0), samples, "replay_cells")[0].endswith("measure more directions")
    # not a BRDF: spatially varying or full-sphere models are not checked
    for attribute in ("spatially_varying", "full_sphere"):
        model = _Scaled(source=half, size=3.0)
        setattr(model, attribute, True)
        assert _energy(model, half) == []
    with pytest.warns(FitWarning, match="reflects more light than it receives: directional albedo 1.5 "):
        res = fit(_Scaled(source=half, size=3.0), half, Recipe(steps=2, batch_size=8, lr=1e-3), progress=False)
    assert len(res.warnings) == 1
