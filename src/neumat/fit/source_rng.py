"""The random number generator a source keeps for itself (an SVBRDF's footprint samples, `SVBRDF.generator`),
as checkpointable state of a fit: a fit that evaluates such a source draws from that generator at every step,
so a resumed fit is only bit-identical to an uninterrupted one when the checkpoint also holds its state. Put
`SourceGenerator(source)` in a phase's `stateful` list."""
from __future__ import annotations

from typing import Any

import torch
from torch import nn


class SourceGenerator(nn.Module):
    """State of `source.generator` (when it is a torch.Generator) as a state_dict: read when the checkpoint is
    written, set when it is loaded. Sources without one give an empty state."""

    def __init__(self, source: Any) -> None:
        super().__init__()
        gen = getattr(source, "generator", None)
        self.generator = gen if isinstance(gen, torch.Generator) else None

    def state_dict(self, *args, **kwargs) -> dict:
        return {} if self.generator is None else {"state": self.generator.get_state()}

    def load_state_dict(self, state_dict, strict: bool = True, assign: bool = False):
        if self.generator is not None and "state" in state_dict:
            self.generator.set_state(state_dict["state"].cpu())
        return nn.modules.module._IncompatibleKeys([], [])
