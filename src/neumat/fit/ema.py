"""Exponential moving average (EMA) of a model's parameters.

After every optimiser step: shadow <- shadow + weight (param - shadow), i.e. (1 - weight) shadow + weight param,
starting from the parameters at construction (no bias correction). Buffers (e.g. pruning levels, frozen
indices) are copied as they are. The shadow is a full copy of the model, so it evaluates like one.
"""
from __future__ import annotations

import copy

import torch
from torch import nn

from ..core.errors import InputError


class EMA:
    """EMA copy of `model` with per-step weight `weight` in (0, 1] of the new parameters."""

    def __init__(self, model: nn.Module, weight: float) -> None:
        if not 0 < weight <= 1:
            raise InputError(f"EMA weight: expected a number in (0, 1], got {weight!r}")
        self.weight = weight
        self.shadow = copy.deepcopy(model)
        self.shadow.requires_grad_(False)

    @torch.no_grad()
    def update(self, model: nn.Module) -> None:
        """Move the shadow towards the current parameters of `model` (same architecture)."""
        params = dict(model.named_parameters())
        shadow = dict(self.shadow.named_parameters())
        if params.keys() != shadow.keys():
            raise InputError("EMA.update: the model's parameters no longer match the EMA copy "
                             f"({sorted(params.keys() ^ shadow.keys())})")
        for name, p in params.items():
            shadow[name].lerp_(p.detach(), self.weight)
        own = dict(self.shadow.named_buffers())
        for name, b in model.named_buffers():
            if name in own:
                own[name].copy_(b)

    def state_dict(self) -> dict:
        return self.shadow.state_dict()

    def load_state_dict(self, state: dict) -> None:
        self.shadow.load_state_dict(state)

    @torch.no_grad()
    def reset(self, model: nn.Module) -> None:
        """Restart the average at the current parameters and buffers of `model` (after a phase changed them
        outside the optimiser, e.g. baked latents)."""
        self.shadow.load_state_dict(model.state_dict())
