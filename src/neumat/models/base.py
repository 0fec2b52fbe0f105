"""LearnedMaterial: the base of every registered model, declaring what the trainer, the model files, the
exporters and `neumat list` use.

Class attributes: `name`, `Config`, `paper`, `source_kinds`. Hooks with do-nothing defaults: `on_step`,
`init_from_targets`, `observe_targets`, `optimizer`, `runtime`, `size_bytes`, `flops`.

Details: docs/notes/fit.md, section `neumat.models.base`.
"""
from __future__ import annotations

from typing import ClassVar

import torch
from torch import nn

from ..core.material import Material

#: kinds of training source: what `source_kinds` names
SOURCE_KINDS = {
    "brdf": "a homogeneous BRDF (measured file, analytic spec, another model)",
    "svbrdf": "a spatially varying material (texture-set folder, layered .json)",
    "btf": "a tabulated BTF (.nbtf, .btf)",
    "btf-set": "several tabulated BTFs (a dictionary is trained on them)",
    "brdf-set": "several homogeneous BRDFs fitted jointly",
    "translucent": "path-traced observations of a translucent object (.npz from `neumat translucent trace`)",
}

#: the precision every size_bytes defaults to: the models' runtime format
DEFAULT_PRECISION = "fp16"


class LearnedMaterial(nn.Module, Material):
    """Base of every registered model (module docstring)."""

    name: ClassVar[str] = "learned"
    Config: ClassVar[type]
    paper: ClassVar[str] = ""
    source_kinds: ClassVar[tuple[str, ...]] = ("brdf",)
    #: rows per slice of an eval over many queries (`neumat.core.tensors.by_rows`): the temporaries of a slice stay
    #: in cache, so the cost per query does not grow from 2^16 to 2^20 queries (issue 49)
    eval_chunk: ClassVar[int] = 2 ** 13

    def on_step(self, step: int, total_steps: int) -> None:
        """Called before every training step (step is 0-based)."""

    def init_from_targets(self, target: torch.Tensor) -> None:
        """Called once before a fresh online fit with the source's values (N, C) at one batch of queries."""

    def observe_targets(self, target: torch.Tensor) -> None:
        """Called with every online training batch's targets (N, C), e.g. to bound the fitted output by them."""

    def optimizer(self, lr: float, betas: tuple[float, float], eps: float) -> torch.optim.Optimizer | None:
        """The model's own optimiser over all its trainable parameters, or None for Adam."""
        return None

    @property
    def is_runtime(self) -> bool:
        """Whether `runtime()` is in effect (model files re-enter it on load)."""
        return False

    def runtime(self) -> "LearnedMaterial":
        """Switch to the shipped form; models without a training-only form are already in it."""
        return self

    def size_bytes(self, precision: str = DEFAULT_PRECISION) -> int:
        """Bytes of the stored runtime form, floats at `precision`."""
        raise NotImplementedError(f"{type(self).__name__}.size_bytes")

    def flops(self) -> int:
        """Floating-point operations of one evaluation."""
        raise NotImplementedError(f"{type(self).__name__}.flops")
