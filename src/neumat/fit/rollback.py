"""The trainer's guard against non-finite steps and parameters: skip, back off, return to the last good state.

`neumat.fit.trainer.fit` keeps one `NonFiniteGuard` per fit: a non-finite step is skipped and the learning
rate halved; after ROLLBACK_AFTER in a row, or at a non-finite parameter, the last good in-memory snapshot is
restored; the fit gives up with an InputError after MAX_ROLLBACKS. The guard's state is checkpointed, so a
resumed fit behaves as the uninterrupted one.

Details: docs/notes/fit.md, section `neumat.fit.rollback`.
"""
from __future__ import annotations

import copy
from typing import Callable

import torch
from torch import nn

from ..core.errors import InputError
from .ema import EMA

#: non-finite steps in a row after which a fit without a snapshot gives up
MAX_SKIPPED_STEPS = 20
#: non-finite steps in a row after which a fit returns to its snapshot. Small, because one overflowing batch is
#: bad luck (skipping it is enough), but several in a row, the learning rate already 2^4 lower, mean that the
#: parameters sit where most batches overflow, and more skipping only wastes steps (the fit of issue 32 skipped
#: its way into an error); a rollback costs just the steps since the snapshot, at most `log_every`.
ROLLBACK_AFTER = 4
#: rollbacks in one fit after which it gives up: by then the learning rate is 2^6 lower or more (2^30 when
#: every rollback followed ROLLBACK_AFTER skipped steps), so the step size is not the cause
MAX_ROLLBACKS = 6
#: checkpoint fields of the guard (`NonFiniteGuard.checkpoint_state`)
CHECKPOINT_KEYS = ("backoff", "skipped", "rollbacks", "restored_from", "snapshot_step", "snapshot")


def take_snapshot(step: int, model: nn.Module, optimizer: torch.optim.Optimizer, ema: EMA | None) -> dict:
    """{"step", "model", "optimizer", "ema"}: the state after `step` steps, every tensor cloned (on its
    device), so that training on does not change it."""
    return {"step": step, "model": copy.deepcopy(model.state_dict()),
            "optimizer": copy.deepcopy(optimizer.state_dict()),
            "ema": copy.deepcopy(ema.state_dict()) if ema is not None else None}


def restore_snapshot(snapshot: dict, model: nn.Module, optimizer: torch.optim.Optimizer, ema: EMA | None) -> None:
    """Load `snapshot` (of `take_snapshot`) into the model (in place: the optimiser keeps its parameters), the
    optimiser and the EMA copy; the snapshot stays unchanged, ready for another rollback."""
    model.load_state_dict(snapshot["model"])
    # an optimiser may keep the loaded tensors themselves as its state (Adam's step count) and update them in
    # place: give it a copy
    optimizer.load_state_dict(copy.deepcopy(snapshot["optimizer"]))
    if ema is not None:
        ema.load_state_dict(snapshot["ema"])


def all_finite(tensors: list[torch.Tensor]) -> bool:
    """Whether every element of the floating-point `tensors` is finite, from one sum per tensor (NaN and inf
    propagate through a sum; in float32 or wider, so a sum overflows only for values near 3e38 / numel,
    which count as not finite) and one device synchronisation. Why sums: `isfinite(t).all()` took 30 times
    longer (525 against 16 ms for 5e7 float32 values on one CPU core)."""
    flags = [torch.isfinite(t.sum(dtype=torch.float32) if t.element_size() < 4 else t.sum()) for t in tensors
             if t.is_floating_point()]
    return bool(torch.stack(flags).all()) if flags else True


class NonFiniteGuard:
    """The guard of one fit (see the module docstring) of `model` named `name`, with its EMA copy `ema` (or
    None), continuing from `state` (a checkpoint's CHECKPOINT_KEYS fields; missing ones as in a fresh fit).
    `report(message)` shows a rollback to the user. The trainer calls `start_phase`, `after_step` after every
    step, `check` at every point, `pop_rollback` for every history record, `end_phase`, and
    `checkpoint_state` for every checkpoint; it multiplies its learning rate by `lr_factor`."""

    def __init__(self, model: nn.Module, ema: EMA | None, name: str, state: dict,
                 report: Callable[[str], None]) -> None:
        self.model, self.ema, self.name, self.report = model, ema, name, report
        self.backoff: int = state.get("backoff", 0)  # halvings of the learning rate so far
        self.skipped: int = state.get("skipped", 0)  # non-finite steps in a row
        # every step since the previous point was finite (checkpoints are written at points, where it restarts)
        self.clean = True
        self.rollbacks: int = state.get("rollbacks", 0)
        self.restored_from: int | None = state.get("restored_from")  # for the next history record
        self._resumed = (state.get("snapshot_step"), state.get("snapshot"))
        self.snapshot: dict | None = None
        self.optimizer: torch.optim.Optimizer | None = None

    @property
    def lr_factor(self) -> float:
        """What the schedule's learning rate is multiplied by: 2^-backoff."""
        return 0.5 ** self.backoff

    def start_phase(self, optimizer: torch.optim.Optimizer | None, step: int, resumed: bool) -> None:
        """A phase starts (or, `resumed`, continues from the checkpoint the guard was made from) at `step`
        with `optimizer` (None: a solver phase, not guarded)."""
        self.optimizer, self.snapshot = optimizer, None
        if optimizer is None:
            return
        if resumed:
            (snapshot_step, stored), self._resumed = self._resumed, (None, None)
            if stored is not None:
                self.snapshot = stored
            elif snapshot_step == step:  # the checkpoint's own state, as loaded
                self.snapshot = take_snapshot(step, self.model, optimizer, self.ema)
            return
        self.skipped, self.clean = 0, True
        if self._parameters_finite():
            self.snapshot = take_snapshot(step, self.model, optimizer, self.ema)

    def after_step(self, finite: bool, done: int, phase: str, scheduled_lr: float) -> None:
        """Step `done` (1-based) of `phase`, at the schedule's rate `scheduled_lr`, had finite gradients (and was
        taken) or not (and was skipped): then halve the learning rate from now on, roll back after
        ROLLBACK_AFTER such steps in a row, give up after MAX_SKIPPED_STEPS without a snapshot."""
        if finite:
            self.skipped = 0
            return
        self.backoff += 1
        self.skipped += 1
        self.clean = False
        if self.snapshot is not None and self.skipped >= ROLLBACK_AFTER:
            self._roll_back(f"the loss or its gradients were not finite at {self.skipped} steps in a row up to "
                            f"step {done}", phase, scheduled_lr)
        elif self.skipped > MAX_SKIPPED_STEPS:
            raise InputError(f"fit {self.name}: the loss or its gradients were not finite at {self.skipped} "
                             f"steps in a row up to step {done} (phase {phase!r}, learning rate backed off to "
                             f"{scheduled_lr * self.lr_factor:g}), with no finite state of the phase to return "
                             "to; lower the learning rate or check the source")

    def check(self, done: int, phase: str, scheduled_lr: float, snapshot: bool) -> None:
        """At a point after step `done`: roll back if a parameter is not finite (give up without a snapshot);
        else, if `snapshot` and every step since the previous point was finite, take a snapshot."""
        if self.optimizer is None:
            return
        if not self._parameters_finite():
            if self.snapshot is None:
                raise InputError(f"fit {self.name}: parameters of the model are not finite after step {done} "
                                 f"(phase {phase!r}), with no finite state of the phase to return to; lower the "
                                 "learning rate or check the model's initialisation")
            self._roll_back(f"parameters of the model were not finite after step {done}", phase, scheduled_lr)
        elif snapshot and self.clean:
            self.snapshot = take_snapshot(done, self.model, self.optimizer, self.ema)
        self.clean = True

    def pop_rollback(self) -> dict:
        """{"rollback": step whose state was restored} once after a rollback (the latest, if several), else {}."""
        note, self.restored_from = self.restored_from, None
        return {} if note is None else {"rollback": note}

    def end_phase(self) -> None:
        """The phase has taken its last step: its snapshot is of no further use."""
        self.optimizer, self.snapshot = None, None

    def checkpoint_state(self, step: int) -> dict:
        """The CHECKPOINT_KEYS fields of a checkpoint after `step` steps; the snapshot itself only when it is
        not the checkpoint's own state."""
        own = self.snapshot is not None and self.snapshot["step"] == step
        return {"backoff": self.backoff, "skipped": self.skipped, "rollbacks": self.rollbacks,
                "restored_from": self.restored_from,
                "snapshot_step": None if self.snapshot is None else self.snapshot["step"],
                "snapshot": None if own else self.snapshot}

    def _parameters_finite(self) -> bool:
        shadow = list(self.ema.shadow.parameters()) if self.ema is not None else []
        return all_finite([p.detach() for p in self.model.parameters()] + shadow)

    def _roll_back(self, why: str, phase: str, scheduled_lr: float) -> None:
        """Restore the snapshot because of `why` (what was not finite, at which step), or give up."""
        if self.rollbacks >= MAX_ROLLBACKS:
            raise InputError(f"fit {self.name}: {why} (phase {phase!r}) after {self.rollbacks} "
                             f"rollbacks to the last finite state (the latest to step {self.snapshot['step']}), the "
                             f"learning rate backed off to {scheduled_lr * self.lr_factor:g} (2^-{self.backoff} of "
                             "the schedule's); lower the learning rate (recipe field lr), clip the gradients "
                             "(grad_clip), or check the source's values and the model's initialisation")
        restore_snapshot(self.snapshot, self.model, self.optimizer, self.ema)
        self.rollbacks += 1
        self.backoff += 1
        self.skipped = 0
        self.restored_from = self.snapshot["step"]
        self.report(f"fit {self.name}: {why} (phase {phase!r}); rolled back to the state after "
                    f"step {self.restored_from}, learning rate now {scheduled_lr * self.lr_factor:g} (rollback "
                    f"{self.rollbacks} of at most {MAX_ROLLBACKS})")
