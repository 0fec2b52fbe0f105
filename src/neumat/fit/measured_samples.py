"""A Material made of measured samples (wi, wo[, uv]) -> value: sparse measurements and replay buffers.

Queries drawn from the samples themselves (`MeasuredSamples.query`, used by the "replay" query sampler)
are answered exactly from storage. Any other query is answered by the nearest stored sample (Euclidean
distance of the concatenated [wi, wo(, uv)] vectors): a piecewise-constant interpolant, so that the
samples are a Material like any other (render, metrics), though a coarse one where they are sparse.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import torch

from ..core.checks import check_directions, check_finite, check_range, check_shape
from ..core.errors import InputError
from ..core.material import Material
from ..core.query import Query


@dataclass
class SampleQuery(Query):
    """A Query whose rows are the stored samples `index` (N,) of `samples`."""

    index: torch.Tensor | None = None
    samples: "MeasuredSamples | None" = field(default=None, repr=False, compare=False)


class MeasuredSamples(Material):
    """N measured BRDF samples.

    wi, wo: (N, 3) unit directions in the upper hemisphere (local frame).
    value:  (N, 3) linear RGB BRDF values, cosine excluded.
    uv:     (N, 2) texture coordinates in [0, 1] for spatially varying measurements, or None.
    """

    can_sample = False

    def __init__(self, wi: torch.Tensor, wo: torch.Tensor, value: torch.Tensor,
                 uv: torch.Tensor | None = None, name: str = "samples") -> None:
        check_directions(wi, f"{name}: wi")
        check_directions(wo, f"{name}: wo")
        n = wi.shape[0]
        if n == 0:
            raise InputError(f"{name}: expected at least one sample")
        check_shape(wo, f"{name}: wo", (n, 3))
        check_shape(value, f"{name}: value", (n, 3))
        check_finite(value, f"{name}: value")
        if bool(((wi[:, 2] < 0) | (wo[:, 2] < 0)).any()):
            raise InputError(f"{name}: wi and wo must lie in the upper hemisphere (z >= 0)")
        if uv is not None:
            check_shape(uv, f"{name}: uv", (n, 2))
            check_range(uv, f"{name}: uv", 0.0, 1.0)
        self.wi, self.wo, self.value, self.uv = wi, wo, value, uv
        self.name = name
        self.spatially_varying = uv is not None
        self._cache: dict = {}

    @classmethod
    def from_material(cls, material: Material, q: Query, name: str | None = None) -> "MeasuredSamples":
        """`material` measured at the queries `q` (values computed without gradient)."""
        with torch.no_grad():
            value = material.eval(q)
        return cls(q.wi, q.wo, value, uv=q.uv, name=name or f"samples of {material.describe()}")

    def reciprocal(self) -> "MeasuredSamples":
        """These samples and each again with wi and wo exchanged (2N; a BRDF is reciprocal, f(wi, wo) = f(wo, wi)).
        Why: a measurement device's outgoing directions are few where its incident ones are many and the other way
        round (an RGL file: 32 x 32 nodes crowded into the specular peak at each of 8 incident elevations), so the
        exchanged pairs cover grazing outgoing directions with the grazing incident measurements."""
        uv = None if self.uv is None else torch.cat([self.uv, self.uv])
        return MeasuredSamples(torch.cat([self.wi, self.wo]), torch.cat([self.wo, self.wi]),
                               torch.cat([self.value, self.value]), uv=uv, name=f"{self.name} and their reciprocals")

    def __len__(self) -> int:
        return self.wi.shape[0]

    def _on(self, device: torch.device) -> dict[str, torch.Tensor]:
        key = str(device)
        if key not in self._cache:
            self._cache[key] = {k: None if t is None else t.to(device)
                                for k, t in (("wi", self.wi), ("wo", self.wo), ("value", self.value), ("uv", self.uv))}
        return self._cache[key]

    def query(self, index: torch.Tensor, dtype: torch.dtype = torch.float32) -> SampleQuery:
        """The stored samples `index` (N,) (on index's device) as a query that `eval` answers exactly."""
        s = self._on(index.device)
        uv = None if s["uv"] is None else s["uv"][index].to(dtype)
        return SampleQuery(s["wi"][index].to(dtype), s["wo"][index].to(dtype), uv=uv, index=index, samples=self)

    def eval(self, q: Query) -> torch.Tensor:
        """Stored values (N, 3) of the samples a `SampleQuery` names; otherwise of the nearest samples."""
        s = self._on(q.device)
        if isinstance(q, SampleQuery) and q.samples is self:
            return s["value"][q.index].to(q.dtype)
        q.require("wo", who=f"{self.name}.eval")
        if self.spatially_varying:
            q.require("uv", who=f"{self.name}.eval (spatially varying samples)")
        return s["value"][self.nearest(q)].to(q.dtype)

    def nearest(self, q: Query) -> torch.Tensor:
        """Index (N,) of the stored sample nearest to each query (brute force, in chunks)."""
        s = self._on(q.device)
        keys = torch.cat([s["wi"], s["wo"]] + ([s["uv"]] if self.spatially_varying else []), -1).float()
        parts = [q.wi, q.wo] + ([q.uv] if self.spatially_varying else [])
        x = torch.cat([p.float() for p in parts], -1)
        if x.shape[0] == 0:
            return torch.zeros(0, dtype=torch.long, device=x.device)
        chunk = max(1, 2 ** 22 // len(self))
        return torch.cat([torch.cdist(x[i:i + chunk], keys).argmin(-1) for i in range(0, x.shape[0], chunk)])

    def describe(self) -> str:
        return f"{self.name} ({len(self)} measured samples{', spatially varying' if self.spatially_varying else ''})"


def table_samples(btf) -> MeasuredSamples:
    """All entries of a tabulated BTF (`neumat.reflectance.btf.TabulatedBTF`) as measured samples
    (wi, wo, uv) -> value, float32, in the entry order of `neumat.models.btf_table_queries.table_queries`: a
    fitting source that the "replay" query sampler draws from exactly (no interpolation between texels or
    direction bins)."""
    from ..models.btf_table_queries import table_queries

    q = table_queries(btf)
    return MeasuredSamples(q.wi, q.wo, btf.data.reshape(-1, 3).to(q.wi), uv=q.uv, name=f"table of {btf.describe()}")


def rgl_samples(material, azimuths: int = 64, min_cos: float = 1e-3) -> MeasuredSamples:
    """The measurement directions of an RGL BRDF (`neumat.reflectance.measured.RglMaterial`) as samples.

    An RGL file stores, for each measured incident direction (its phi_i x theta_i grid, 1 x 8 in the shared
    files), an R x R table (32 x 32) of values at the nodes of its warped domain: node (x, y) = (j, i) / (R - 1)
    is the outgoing direction that the file's VNDF warp maps it to (as `RglMaterial.sample` does). These
    P T R^2 (wi, wo) pairs are what was measured; their values are the material's own (its interpolant
    at a node is the node's value). An isotropic file measures one incident azimuth: every pair is also
    rotated about the normal to `azimuths` equally spaced azimuths (the same values, by isotropy), so the
    samples cover wi on T rings and are still sparse in theta_i. Pairs with cos theta_i or cos theta_o
    below `min_cos` (the grazing theta_i = 90 degrees row) are left out. Returns N = azimuths x (kept pairs)
    samples (1 azimuth for an anisotropic file)."""
    from ..reflectance.measured import RglMaterial

    if not isinstance(material, RglMaterial):
        raise InputError(f"rgl_samples: expected an RGL material (a *_rgb.bsdf file), got {type(material).__name__}")
    if isinstance(azimuths, bool) or not isinstance(azimuths, int) or azimuths < 1:
        raise InputError(f"rgl_samples azimuths: expected a positive integer, got {azimuths!r}")
    rgb = material.rgb
    phi, theta = (p.float() for p in rgb.param_values)
    r_h, r_w = rgb.h, rgb.w
    y, x = torch.meshgrid(torch.arange(r_h) / (r_h - 1), torch.arange(r_w) / (r_w - 1), indexing="ij")
    node = torch.stack([x.reshape(-1), y.reshape(-1)], -1)                       # (R^2, 2)
    p_i, t_i = (g.reshape(-1) for g in torch.meshgrid(phi, theta, indexing="ij"))  # (P T,)
    m_in = node.shape[0]
    s = node.repeat(p_i.shape[0], 1)
    params = [p_i.repeat_interleave(m_in), t_i.repeat_interleave(m_in)]
    u_m, _ = material.vndf.sample(s, params)
    phi_m = (2 * u_m[:, 1] - 1) * torch.pi + (params[0] if material.isotropic else 0)
    theta_m = u_m[:, 0] ** 2 * (torch.pi / 2)
    m = torch.stack([torch.cos(phi_m) * torch.sin(theta_m), torch.sin(phi_m) * torch.sin(theta_m),
                     torch.cos(theta_m)], -1)
    wi = torch.stack([torch.cos(params[0]) * torch.sin(params[1]), torch.sin(params[0]) * torch.sin(params[1]),
                      torch.cos(params[1])], -1)
    wo = 2 * (wi * m).sum(-1, keepdim=True) * m - wi
    wo = wo / wo.norm(dim=-1, keepdim=True)
    keep = (wi[:, 2] > min_cos) & (wo[:, 2] > min_cos)
    wi, wo = wi[keep], wo[keep]
    with torch.no_grad():
        value = material.eval(Query(wi, wo)).float()
    if material.isotropic and azimuths > 1:
        a = torch.arange(azimuths, dtype=torch.float32) * (2 * torch.pi / azimuths)
        c, s_ = torch.cos(a)[:, None], torch.sin(a)[:, None]

        def rotate(v: torch.Tensor) -> torch.Tensor:  # (N, 3) -> (azimuths N, 3)
            return torch.stack([c * v[:, 0] - s_ * v[:, 1], s_ * v[:, 0] + c * v[:, 1],
                                v[:, 2].expand(azimuths, -1)], -1).reshape(-1, 3)

        wi, wo, value = rotate(wi), rotate(wo), value.repeat(azimuths, 1)
    return MeasuredSamples(wi, wo, value, name=f"measurements of {material.name}")
