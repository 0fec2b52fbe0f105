"""L2 fits of translucent-object models to path-traced observations, with optional early stopping on held-back
observations: the loop shared by NeuPreSS and the dipole baseline."""
from __future__ import annotations

import math
from typing import Callable, Sequence

import torch

from ..core.checks import check_int
from ..core.errors import InputError
from .adam_steps import adam_steps
from .translucent_observations import Observations

Predict = Callable[[Observations], torch.Tensor]


def fit_observations(predict: Predict, params: Sequence[torch.nn.Parameter], observations: Observations,
                     steps: int, batch: int, lr: float, seed: int = 0, progress: bool = False, log_every: int = 100,
                     validation: Observations | None = None, description: str = "fit") -> list[dict]:
    """Adam on the mean squared error of predict(obs) (N, 3) against obs.value over random batches (lr halved at
    50% and 75% of `steps`). With `validation`, every record also holds "validation_mse" and `params` end with
    the values of the record where that was lowest. Returns the loss history of `adam_steps`."""
    for name, v in (("steps", steps), ("batch", batch)):
        check_int(v, f"{description} {name}")
    gen = torch.Generator().manual_seed(seed)
    params = list(params)

    def step():
        idx = torch.randint(len(observations), (batch,), generator=gen)
        o = observations[idx]
        return (((predict(o) - o.value) ** 2).mean(),)

    if validation is None:
        return adam_steps(params, steps, lr, step, ["mse"], description, log_every, progress)
    if len(validation) == 0:
        raise InputError(f"{description} validation: expected at least one observation, got none")
    best = {"mse": math.inf, "weights": None}

    def keep_best(record: dict) -> None:
        record["validation_mse"] = observation_mse(predict, validation, batch)
        if record["validation_mse"] < best["mse"]:
            best["mse"] = record["validation_mse"]
            best["weights"] = [p.detach().clone() for p in params]

    history = adam_steps(params, steps, lr, step, ["mse"], description, log_every, progress, keep_best)
    if best["weights"] is None:
        raise InputError(f"{description}: the validation MSE was never finite ({history[-1]['validation_mse']}); "
                         f"the fit diverged (lower lr, now {lr})")
    with torch.no_grad():
        for p, w in zip(params, best["weights"]):
            p.copy_(w)
    return history


def observation_mse(predict: Predict, observations: Observations, batch: int = 65536) -> float:
    """Mean squared error of predict on `observations` (per channel), without gradients."""
    total = 0.0
    with torch.no_grad():
        for i in range(0, len(observations), batch):
            o = observations[i:i + batch]
            total += float(((predict(o) - o.value) ** 2).sum())
    return total / (len(observations) * observations.value.shape[-1])
