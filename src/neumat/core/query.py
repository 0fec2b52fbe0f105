"""`Query` (what a material is asked) and `Sample` (what a sampler returns).

Directions are in the local shading frame (z = normal, x = tangent), unit length, pointing
away from the surface: `wi` towards the light, `wo` towards the viewer.
"""
from __future__ import annotations

from dataclasses import dataclass, fields

import torch

from .checks import check_directions, check_finite, check_shape
from .errors import InputError


@dataclass
class Query:
    """A batch of N material queries.

    wi, wo:    (N, 3) unit directions (local frame; object space for translucent objects).
    uv:        (N, 2) texture coordinates in [0, 1] (spatially varying materials), or None.
    footprint: (N, 2, 2) symmetric positive definite texture-space filter Sigma (uv units^2), or None.
    lod:       (N,) mip level, or None.
    x:         (N, 3) object-space position (translucent objects), or None.
    n:         (N, 3) unit object-space outward surface normal at x (translucent objects), or None.
    """

    wi: torch.Tensor
    wo: torch.Tensor | None = None
    uv: torch.Tensor | None = None
    footprint: torch.Tensor | None = None
    lod: torch.Tensor | None = None
    x: torch.Tensor | None = None
    n: torch.Tensor | None = None

    def __post_init__(self) -> None:
        check_directions(self.wi, "Query.wi")
        n = self.wi.shape[0]
        if self.wo is not None:
            check_directions(self.wo, "Query.wo")
        shapes = {"wo": (n, 3), "uv": (n, 2), "footprint": (n, 2, 2), "lod": (n,), "x": (n, 3), "n": (n, 3)}
        for name, shape in shapes.items():
            t = getattr(self, name)
            if t is not None:
                self._check_field(name, t, shape, finite=name != "wo")  # check_directions covered wo's

    def _check_field(self, name: str, t: torch.Tensor, shape: tuple, finite: bool = True) -> None:
        """Shape, finiteness (unless `finite` is False: the caller checked it) and wi's dtype of the field `name`
        (its unit length, if a direction, is checked by the caller)."""
        check_shape(t, f"Query.{name}", shape)
        if finite:
            check_finite(t, f"Query.{name}")
        if t.dtype != self.wi.dtype:
            raise InputError(f"Query.{name} is {t.dtype} but Query.wi is {self.wi.dtype}: give every field of a "
                             "query one floating-point dtype")

    @classmethod
    def trusted(cls, wi: torch.Tensor, wo: torch.Tensor | None = None, uv: torch.Tensor | None = None,
                footprint: torch.Tensor | None = None, lod: torch.Tensor | None = None,
                x: torch.Tensor | None = None, n: torch.Tensor | None = None) -> "Query":
        """A Query built without validation (no shape, finiteness or unit-length checks, no host syncs).

        Only for internal hot loops (the renderer) whose tensors are correct by construction; everything
        else should call `Query(...)`.
        """
        q = object.__new__(cls)
        q.__dict__.update(wi=wi, wo=wo, uv=uv, footprint=footprint, lod=lod, x=x, n=n)
        return q

    def __len__(self) -> int:
        return self.wi.shape[0]

    @property
    def device(self) -> torch.device:
        return self.wi.device

    @property
    def dtype(self) -> torch.dtype:
        return self.wi.dtype

    def require(self, *names: str, who: str = "material") -> None:
        """Raise a clear error if one of the named optional fields is missing."""
        for name in names:
            if getattr(self, name) is None:
                raise InputError(f"{who} needs Query.{name}, but the query has none")

    def with_wo(self, wo: torch.Tensor | None) -> "Query":
        """The same query with outgoing directions `wo` (N, 3), or without them (None): only `wo` is checked (the
        other fields were when this query was built), which keeps the samplers' per-call overhead down."""
        if wo is not None:
            check_directions(wo, "Query.wo")
            self._check_field("wo", wo, (len(self), 3), finite=False)
        return self._derived(wo=wo)

    def swapped(self) -> "Query":
        """The query with wi and wo exchanged (for reciprocity)."""
        if self.wo is None:
            raise InputError("Query.swapped needs Query.wo")
        return self._derived(wi=self.wo, wo=self.wi)  # both were checked as directions of one dtype

    def _derived(self, **changes) -> "Query":
        """This query with `changes`, not checked again: for fields derived from checked ones."""
        q = object.__new__(type(self))
        q.__dict__.update(self.__dict__, **changes)
        return q

    def to(self, device=None, dtype=None) -> "Query":
        """Move every tensor field to `device` / `dtype`: this query itself where they are there already, else a
        new one, checked (a conversion can round)."""
        kw = {}
        for f in fields(self):
            t = getattr(self, f.name)
            kw[f.name] = None if t is None else t.to(device=device, dtype=dtype)
        if all(kw[f.name] is getattr(self, f.name) for f in fields(self)):
            return self
        return Query(**kw)

    def __getitem__(self, index) -> "Query":
        """Select a sub-batch (slice, bool mask or index tensor). Rows of a checked query are not checked again;
        other indices (an int, a 2D index) give a new query that is, as their shapes may not fit."""
        kw = {}
        for f in fields(self):
            t = getattr(self, f.name)
            kw[f.name] = None if t is None else t[index]
        if isinstance(index, slice) or (isinstance(index, torch.Tensor) and index.dim() == 1):
            return self._derived(**kw)
        return Query(**kw)


@dataclass
class Sample:
    """Result of importance sampling an outgoing direction.

    wo:     (N, 3) sampled unit direction.
    pdf:    (N,) solid-angle density of wo (0 where sampling failed).
    weight: (N, 3) eval * cos(theta_o) / pdf (0 where sampling failed).
    """

    wo: torch.Tensor
    pdf: torch.Tensor
    weight: torch.Tensor
