"""A short Adam run on losses a step function computes: the loop shared by the fits that do not go through
`neumat.fit.trainer` (the proxy sampler, the two phases of neural-appearance training)."""
from __future__ import annotations

from typing import Callable, Iterable, Sequence

import torch


def adam_steps(params: Iterable[torch.nn.Parameter], steps: int, lr: float,
               step_fn: Callable[[], Sequence[torch.Tensor]], names: Sequence[str], description: str,
               log_every: int, progress: bool, on_record: Callable[[dict], None] | None = None) -> list[dict]:
    """`steps` Adam steps (learning rate `lr`, halved at 50% and 75% of the steps) on the sum of the losses
    step_fn() returns, one per name of `names`. Returns a record {"step", <name>: mean loss since the last
    record} every `log_every` steps and after the last; `on_record(record)` sees each record as it is made
    and may add fields to it (a validation loss, say)."""
    opt = torch.optim.Adam(params, lr=lr)
    sched = torch.optim.lr_scheduler.MultiStepLR(opt, [steps // 2, 3 * steps // 4], gamma=0.5)
    iterator = range(steps)
    if progress:
        from rich.progress import track
        iterator = track(iterator, description=description)
    history, sums = [], [0.0] * len(names)
    for step in iterator:
        losses = step_fn()
        opt.zero_grad()
        sum(losses).backward()
        opt.step()
        sched.step()
        sums = [a + b.item() for a, b in zip(sums, losses)]
        if (step + 1) % log_every == 0 or step + 1 == steps:
            count = step % log_every + 1
            history.append({"step": step + 1, **{n: v / count for n, v in zip(names, sums)}})
            if on_record is not None:
                on_record(history[-1])
            sums = [0.0] * len(names)
    return history
