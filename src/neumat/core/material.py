"""The `Material` protocol shared by ground-truth sources and learned models."""
from __future__ import annotations

import functools
from typing import Any

import torch
from torch import nn

from .errors import InputError
from .query import Query, Sample
from .tensors import cached_tensor


class Material:
    """Anything that answers batched reflectance queries.

    Subclasses implement `eval`; samplers also implement `sample` and `pdf` and set
    `can_sample = True`. Values are linear RGB BRDF values without the cosine factor.

    Learned models are also `torch.nn.Module`s, whose `eval()` (no argument) switches to inference mode.
    Both meanings are kept: on a Module subclass, `eval()` without a query calls `nn.Module.eval` and
    `eval(q)` evaluates the material.
    """

    def __init_subclass__(cls, **kwargs) -> None:
        super().__init_subclass__(**kwargs)
        own = cls.__dict__.get("eval")
        if own is not None and issubclass(cls, nn.Module):
            cls.eval = _keep_module_eval(own)

    #: registry / display name
    name: str = "material"
    #: whether `sample` and `pdf` are implemented
    can_sample: bool = False
    #: whether the material needs Query.uv (and uses footprint / lod when given)
    spatially_varying: bool = False
    #: whether directions span the whole sphere (translucent objects) instead of the upper hemisphere
    full_sphere: bool = False

    def eval(self, q: Query) -> torch.Tensor:
        """BRDF value f(wi, wo), shape (N, 3), linear RGB, cosine excluded."""
        raise NotImplementedError(f"{type(self).__name__}.eval")

    def sample(self, q: Query, u: torch.Tensor) -> Sample:
        """Sample wo given q.wi and uniform numbers u (N, 2) in [0, 1)."""
        raise NotImplementedError(f"{type(self).__name__} cannot sample (can_sample = False)")

    def sample_direction(self, q: Query, u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """wo (N, 3) and its density (N,) (0: a failed sample) as `sample` draws them, without the weight.
        For callers that need only the direction (mixtures, query generators); materials whose weight costs
        an evaluation override it."""
        s = self.sample(q, u)
        return s.wo, s.pdf

    def pdf(self, q: Query) -> torch.Tensor:
        """Solid-angle density (N,) with which `sample` produces q.wo given q.wi."""
        raise NotImplementedError(f"{type(self).__name__} has no pdf (can_sample = False)")

    def __call__(self, q: Query) -> torch.Tensor:
        return self.eval(q)

    def describe(self) -> str:
        """One line for tables and CLI output."""
        return self.name


class NonNegative(Material):
    """`material` with negative values read as 0. Why: measured tables keep negative noise (RGL files down to
    -1.4 % of their maximum), which no fit reproduces (every loss clamps its targets) and which darkens a
    rendered reference where a channel is near 0 (`neumat.render.comparison`)."""

    def __init__(self, material: Material) -> None:
        self.material = material
        self.name = getattr(material, "name", type(material).__name__)
        self.can_sample = material.can_sample
        self.spatially_varying = material.spatially_varying
        self.full_sphere = material.full_sphere
        self.device = material_device(material)

    def eval(self, q: Query) -> torch.Tensor:
        return self.material.eval(q).clamp(min=0)

    def sample(self, q: Query, u: torch.Tensor) -> Sample:
        s = self.material.sample(q, u)
        return Sample(s.wo, s.pdf, s.weight.clamp(min=0))

    def sample_direction(self, q: Query, u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.material.sample_direction(q, u)

    def pdf(self, q: Query) -> torch.Tensor:
        return self.material.pdf(q)

    def describe(self) -> str:
        return self.material.describe()


def describe_source(source: Any) -> str:
    """One line naming a fit's source: its `describe()`, else its type's name (target sources such as measured
    samples need not be materials)."""
    return source.describe() if hasattr(source, "describe") else type(source).__name__


def material_device(*materials: Material) -> torch.device:
    """Device of the first material that has one, else CPU: a `device` attribute (wrappers that hold modules
    declare theirs), or an nn.Module's first parameter or buffer."""
    for material in materials:
        declared = getattr(material, "device", None)
        if isinstance(declared, torch.device):
            return declared
        if isinstance(material, nn.Module):
            for t in (*material.parameters(), *material.buffers()):
                return t.device
    return torch.device("cpu")


def _keep_module_eval(evaluate):
    """`evaluate(self, q, ...)` that, called with no arguments, is `nn.Module.eval(self)` instead."""

    @functools.wraps(evaluate)
    def eval(self, *args, **kwargs):
        if not args and not kwargs:
            return nn.Module.eval(self)
        return evaluate(self, *args, **kwargs)

    return eval


def check_sample_u(q: Query, u) -> torch.Tensor:
    """The uniform numbers u of `Material.sample(q, u)`: a floating-point tensor of shape (len(q), 2) with values
    in [0, 1), else InputError; returned in the query's dtype and device (values that round up to 1 there kept just
    below it), so a float64 u with a float32 query samples as the float32 u would (it used to fail inside some
    materials with an error about Query.wo, a field the caller never gave)."""
    if not isinstance(u, torch.Tensor) or u.shape != (len(q), 2):
        raise InputError(f"u: expected a tensor of shape ({len(q)}, 2), got {getattr(u, 'shape', type(u))}")
    if not u.is_floating_point():
        raise InputError(f"u: expected floating-point numbers in [0, 1), got dtype {u.dtype}")
    if u.numel() and not bool(((u >= 0) & (u < 1)).all()):
        raise InputError(f"u: expected values in [0, 1), got [{u.min().item():.4g}, {u.max().item():.4g}]"
                         f"{' and NaN' if bool(u.isnan().any()) else ''}")
    if u.dtype == q.wi.dtype and u.device == q.wi.device:
        return u
    below_one = torch.nextafter(torch.ones((), dtype=q.wi.dtype), torch.zeros((), dtype=q.wi.dtype))
    return u.to(q.wi.device, q.wi.dtype).clamp(max=float(below_one))


def upper_hemisphere(wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
    """Mask (N,) of queries with both directions strictly above the surface (one minimum and one comparison:
    models mask every evaluation with it)."""
    return torch.minimum(wi[:, 2], wo[:, 2]) > 0


def zero_below_horizon(f: torch.Tensor, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
    """f (N, C) with 0 where wi or wo is not strictly above the surface (`upper_hemisphere`): how every model's
    evaluation ends; the zero is one cached 0-dim tensor, not a zeros_like allocation per call."""
    return torch.where(upper_hemisphere(wi, wo).unsqueeze(-1), f, cached_tensor(0.0, f.dtype, f.device))


def sample_from_direction(material: Material, q: Query, u: torch.Tensor) -> Sample:
    """`material.sample` for materials that implement `sample_direction`: the drawn wo and pdf, weighted by one
    evaluation (failed draws, pdf 0, get weight 0). u is checked (`check_sample_u`)."""
    wo, pdf = material.sample_direction(q, check_sample_u(q, u))
    return Sample(wo, pdf, sample_weight(material.eval(q.with_wo(wo)), wo, pdf, pdf > 0))


def sample_weight(f: torch.Tensor, wo: torch.Tensor, pdf: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """weight = f * cos(theta_o) / pdf, zero where `valid` is false or pdf is 0. Shapes (N,3),(N,3),(N,),(N,)."""
    ok = valid & (pdf > 0)
    w = f * (wo[:, 2].clamp(min=0) / torch.where(ok, pdf, torch.ones_like(pdf))).unsqueeze(-1)
    return torch.where(ok.unsqueeze(-1), w, torch.zeros_like(w))
