"""The trainer's guard against non-finite values (`neumat.fit.rollback`): a non-finite step is skipped and halves
the learning rate; a run of them, or non-finite parameters, roll the fit back to its last good snapshot; a fit
that stays non-finite gives up with a clear error; a resumed fit rolls back as an uninterrupted one; the
snapshot of a NeuBRDF with row-sparse Adam restores exactly and survives training after a restore."""
from __future__ import annotations

import copy
import math

import pytest
import torch
from torch import nn

from neumat.core.errors import InputError
from neumat.core.material import Material
from neumat.core.query import Query
from neumat.fit.ema import EMA
from neumat.fit.recipe import Recipe
from neumat.fit.rollback import MAX_ROLLBACKS, MAX_SKIPPED_STEPS, ROLLBACK_AFTER, restore_snapshot, take_snapshot
from neumat.fit.trainer import fit
from neumat.models.base import LearnedMaterial
from neumat.methods.neubrdf.model import NeuBRDF
from neumat.warp.hemisphere import sample_cosine_hemisphere


class Grey(Material):
    """A constant BRDF 0.2."""

    name = "grey"

    def eval(self, q: Query) -> torch.Tensor:
        return torch.full((len(q), 3), 0.2, dtype=q.dtype, device=q.device)


class Interrupt(Exception):
    pass


class Flaky(LearnedMaterial):
    """A learnable constant BRDF exp(p) whose output is NaN at the (0-based) steps `bad_steps`, as a model that
    overflows for a while; `spare` is a parameter the output does not use. Raises Interrupt before step
    `interrupt_at`."""

    name = "flaky"

    def __init__(self, bad_steps=(), interrupt_at: int | None = None) -> None:
        super().__init__()
        self.p = nn.Parameter(torch.tensor([-1.0, 0.0, 0.5]))
        self.spare = nn.Parameter(torch.zeros(2))
        self.bad_steps = set(bad_steps)
        self.interrupt_at = interrupt_at
        self.bad = False

    def eval(self, q: Query) -> torch.Tensor:
        f = torch.exp(self.p).expand(len(q), 3)
        return f * math.nan if self.bad else f

    def on_step(self, step: int, total: int) -> None:
        if step == self.interrupt_at:
            raise Interrupt
        self.bad = step in self.bad_steps


def _recipe(**kw) -> Recipe:
    return Recipe(**{"steps": 24, "batch_size": 8, "lr": 0.05, "loss": "l2", "log_every": 2, **kw})


def _recording(model: Flaky, seen: dict):
    """A fit callback that stores the model's `p` at every history record in `seen` (step -> p)."""
    def callback(record: dict) -> None:
        seen[record["step"]] = model.p.detach().clone()
    return callback


def test_non_finite_step_is_skipped_and_halves_the_learning_rate():
    m = Flaky(bad_steps={2})
    seen = {}
    res = fit(m, Grey(), _recipe(steps=5, lr=0.1, log_every=1), progress=False, callback=_recording(m, seen))
    assert [r["lr"] for r in res.history] == [0.1, 0.1, 0.1, 0.05, 0.05]
    assert math.isnan(res.history[2]["loss"]) and all(math.isfinite(r["loss"]) for r in res.history[3:])
    assert torch.equal(seen[3], seen[2]) and not torch.equal(seen[4], seen[3])  # step 3 skipped, 4 taken
    assert not any("rollback" in r for r in res.history)


def test_window_of_non_finite_steps_rolls_back_to_the_last_snapshot(capsys):
    """Snapshots at records 2, 4, 6; steps 8-15 (1-based) overflow: after ROLLBACK_AFTER of them (at step 11
    and again at 15) the fit returns to the state after step 6, each time with the learning rate 2^5 lower
    (4 skips, 1 rollback); it ends finite."""
    assert ROLLBACK_AFTER == 4
    m = Flaky(bad_steps=range(7, 15))
    seen = {}
    res = fit(m, Grey(), _recipe(ema=0.5), progress=True, callback=_recording(m, seen))
    assert {r["step"]: r["rollback"] for r in res.history if "rollback" in r} == {12: 6, 16: 6}
    assert not torch.equal(seen[8], seen[6]) and torch.equal(seen[12], seen[6])  # step 7 moved p, 11 restored it
    assert res.history[-1]["lr"] == 0.05 * 0.5 ** 10 and math.isfinite(res.history[-1]["loss"])
    assert all(bool(torch.isfinite(p).all()) for p in m.parameters())
    err = capsys.readouterr().err
    assert "up to step 11 (phase 'fit'); rolled back to the state after step 6" in err
    assert "(rollback 2 of at most 6)" in err


@pytest.mark.parametrize("poisoned, halvings", [("p", 3), ("spare", 1)])
def test_parameters_poisoned_mid_fit_are_restored_at_the_next_record(poisoned, halvings):
    """A callback sets a parameter to NaN after the record (and snapshot) of step 4: the next record finds it
    non-finite and rolls back to step 4, whether the loss saw it (p: steps 5 and 6 skipped, then the
    rollback, 3 halvings of the learning rate) or not (spare: the rollback's halving only)."""
    m = Flaky()

    def poison(record):
        if record["step"] == 4:
            getattr(m, poisoned).data.fill_(math.nan)

    res = fit(m, Grey(), _recipe(steps=10), progress=False, callback=poison)
    assert [r.get("rollback") for r in res.history] == [None, None, 4, None, None]
    assert all(bool(torch.isfinite(p).all()) for p in m.parameters())
    assert all(math.isfinite(r["loss"]) for r in res.history[3:])
    assert res.history[-1]["lr"] == 0.05 * 0.5 ** halvings


def test_non_finite_forever_gives_up_after_the_rollbacks(tmp_path):
    """Steps 5 on overflow: rollbacks to step 4 at steps 8, 12, ..., 28, then the error at step 32; also when
    the fit was interrupted after the checkpoint of step 20 (4 rollbacks done) and resumed."""
    recipe = _recipe(steps=200, checkpoint_every=10)
    error = rf"fit flaky: .*not finite at 4 steps in a row up to step 32 \(phase 'fit'\) after {MAX_ROLLBACKS} " \
            r"rollbacks .*step 4\).*lower the learning"
    with pytest.raises(InputError, match=error):
        fit(Flaky(bad_steps=range(4, 10 ** 6)), Grey(), recipe, progress=False)
    ckpt = tmp_path / "fit.ckpt"
    with pytest.raises(Interrupt):
        fit(Flaky(range(4, 10 ** 6), interrupt_at=20), Grey(), recipe, progress=False, checkpoint=ckpt)
    assert torch.load(ckpt, weights_only=True)["rollbacks"] == 4
    with pytest.raises(InputError, match=error):
        fit(Flaky(range(4, 10 ** 6)), Grey(), recipe, progress=False, checkpoint=ckpt, resume=True)


@pytest.mark.parametrize("log_every, match", [
    (50, f"not finite at {MAX_SKIPPED_STEPS + 1} steps in a row up to step {MAX_SKIPPED_STEPS + 1} .*no finite "
         "state"),
    (2, "parameters of the model are not finite after step 2 .*no finite state"),
])
def test_non_finite_from_the_start_gives_up_without_a_snapshot(log_every, match):
    """Parameters non-finite when the phase starts: no snapshot, so the old rule (give up after
    MAX_SKIPPED_STEPS non-finite steps in a row) or, at a record, the parameter check ends the fit."""
    m = Flaky()
    m.p.data[0] = math.nan
    with pytest.raises(InputError, match=match):
        fit(m, Grey(), _recipe(steps=100, log_every=log_every), progress=False)


def test_resume_after_a_rollback_equals_the_uninterrupted_run(tmp_path):
    """Records every 2 steps, checkpoints every 3, EMA; steps 12-15 and 20-23 overflow (1-based), so the fit
    rolls back to step 10 at step 15 and to step 18 at step 23. Interrupted after the checkpoint of step 12
    (two steps skipped; its snapshot, of step 10, is older: the checkpoint holds it), of step 15 (just rolled
    back, not yet recorded) or of step 18 (its own state is the snapshot), the resumed fit ends bit for bit as
    the uninterrupted one."""
    bad = [*range(11, 15), *range(19, 23)]
    recipe = _recipe(steps=26, checkpoint_every=3, ema=0.3)

    def run(checkpoint=None, resume=False, interrupt_at=None):
        m = Flaky(bad, interrupt_at)
        return m, fit(m, Grey(), recipe, progress=False, checkpoint=checkpoint, resume=resume)

    ref_model, ref = run()
    assert {r["step"]: r["rollback"] for r in ref.history if "rollback" in r} == {16: 10, 24: 18}
    strip = lambda h: [{k: repr(v) for k, v in r.items() if k != "seconds"} for r in h]  # noqa: E731 (NaN == NaN)
    for stop, snapshot_step, stored, restored_from in ((12, 10, True, None), (15, 10, True, 10), (18, 18, False, None)):
        ckpt = tmp_path / f"stop{stop}.ckpt"
        with pytest.raises(Interrupt):
            run(ckpt, interrupt_at=stop)
        blob = torch.load(ckpt, weights_only=True)
        assert blob["step"] == stop and blob["snapshot_step"] == snapshot_step
        assert (blob["snapshot"] is not None) == stored and blob["restored_from"] == restored_from
        model, res = run(ckpt, resume=True)
        assert all(torch.equal(ref_model.state_dict()[k], v) for k, v in model.state_dict().items())
        assert strip(res.history) == strip(ref.history)


def _same(a, b) -> bool:
    """Equal nested state (dicts, lists, tensors bit for bit)."""
    if isinstance(a, torch.Tensor):
        return isinstance(b, torch.Tensor) and a.dtype == b.dtype and torch.equal(a, b)
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    return a == b


def test_snapshot_of_neubrdf_with_row_sparse_adam_restores_exactly():
    """A VQ NeuBRDF trained by its RowAdam (sparse row gradients of the logits) with an EMA: restoring a
    snapshot gives back the model, optimiser and EMA state bit for bit, and training after a restore leaves
    the snapshot as it was (a second restore and the same step give the same result)."""
    torch.manual_seed(0)
    m = NeuBRDF(nside=2, index_bits=3, hidden=8)
    opt, ema = m.optimizer(0.01), EMA(m, 0.5)
    g = torch.Generator().manual_seed(1)
    q = Query(sample_cosine_hemisphere(torch.rand(64, 2, generator=g)),
              sample_cosine_hemisphere(torch.rand(64, 2, generator=g)))

    def step():
        opt.zero_grad(set_to_none=True)
        m.eval(q).log().square().mean().backward()
        assert m.grid.logits.grad.is_sparse
        opt.step()
        ema.update(m)

    step()
    snap = take_snapshot(1, m, opt, ema)
    before = [copy.deepcopy(s) for s in (m.state_dict(), opt.state_dict(), ema.state_dict())]
    step()
    step()
    assert not _same(m.state_dict(), before[0])
    restore_snapshot(snap, m, opt, ema)
    assert all(_same(a, b) for a, b in zip((m.state_dict(), opt.state_dict(), ema.state_dict()), before))
    step()
    once = copy.deepcopy(m.state_dict())
    restore_snapshot(snap, m, opt, ema)
    step()
    assert _same(m.state_dict(), once)
