"""LearnedMaterial: the base of every registered model, declaring what the trainer, the model files, the
exporters and `neumat list` use.

A model is a torch `nn.Module` answering the Material protocol (`eval`, and `sample` / `pdf` where it
samples). Class attributes say what it is; the hooks have do-nothing defaults, so a model overrides only
what it needs:

    name          registry name (also the recipe module's: `neumat.fit.recipes.<name, '-' -> '_'>`)
    Config        its config dataclass (paper defaults, one docstring per field); instances keep it as `cfg`
    paper         the publication it implements, or what it is a baseline of
    source_kinds  the kinds of source it fits (see SOURCE_KINDS)
    on_step(step, total_steps)      before every training step (annealing, freezing)
    init_from_targets(target)       once before a fresh online fit, with the source's values at one batch
    optimizer(lr, betas, eps)       its own optimiser, or None for Adam on all trainable parameters
    runtime()                       switch to the form that is shipped (packed, no training state); returns self
    size_bytes(precision)           stored size of the runtime form; every model defaults to fp16
    flops()                         floating-point operations of one evaluation
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

    def on_step(self, step: int, total_steps: int) -> None:
        """Called before every training step (step is 0-based)."""

    def init_from_targets(self, target: torch.Tensor) -> None:
        """Called once before a fresh online fit with the source's values (N, C) at one batch of queries."""

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
