"""NeuBRDF with neural reflectance primitives shared across materials (Dou et al. 2024, Sec. 3.3).

A cluster of t similar materials shares one MLP and one codebook D (2^b, k); each material keeps only its
own spherical index grid (2 n b-bit indices). The clusters come from a convolutional autoencoder trained to
reconstruct tabulated reflectance, then k-means on its bottleneck codes (`cluster_materials`). The shared
modules and the t index grids are trained jointly (`fit_shared`, `fit_clusters`).

Joint training runs through the shared trainer `neumat.fit.trainer.fit`: a `MaterialQuery` carries, per
row, the index of the material it asks; a `JointSource` answers it from the t source materials and the
model evaluates every row on that material's index grid, so one batch mixes all materials (the "joint"
query sampler draws an equal share of each batch per material with that material's base sampler).

Storage: all index grids live in one `VQFeatures` of t * 2n vertices, whose storage formula is exactly
t 2n b + p k 2^b bits; see `sharing_cost` for the bytes per material with and without sharing.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace
from typing import Sequence

import numpy as np
import torch
from torch import nn

from neumat.core.checks import check_directions, check_int, check_shape
from neumat.core.config import resolve_config
from neumat.core.coords import rusinkiewicz_to_io
from neumat.core.errors import InputError
from neumat.core.material import Material, upper_hemisphere
from neumat.core.query import Query
from neumat.models.base import LearnedMaterial
from neumat.fit.query_samplers import QUERY_SAMPLERS
from neumat.fit.recipe import Recipe, recipe_for
from neumat.models.registry import MODELS
from neumat.nn import healpix as hpx
from neumat.nn.codebook import VQFeatures, float_bits, storage_bytes
from neumat.nn.conv_autoencoder import ConvAutoencoder, train_autoencoder
from neumat.nn.mlp import MLP


@dataclass
class Config:
    """Shared NeuBRDF hyper-parameters; the grid / codebook / MLP defaults are NeuBRDF's (paper Sec. 4)."""

    num_materials: int = 2
    """t, materials of the cluster (one index grid each)."""
    nside: int = 64
    """HEALPix resolution of every index grid (a power of two)."""
    feature_dim: int = 16
    """k, dimension of a neural reflectance primitive."""
    index_bits: int = 9
    """b, bits of a codebook index; the shared codebook has 2^b rows."""
    hidden: int = 64
    """Neurons per hidden layer of the shared MLP."""
    hidden_layers: int = 2
    """Hidden layers of the shared MLP."""
    activation: str = "leaky_relu"
    """Hidden activation of the shared MLP (as NeuBRDF's; see `neumat.models.neubrdf.Config`)."""
    interpolation: str = "idw"
    """Corner weights: "idw" (inverse great-circle distance, training) or "uniform" (1/4, runtime)."""


def _check_config(c: Config) -> None:
    for name, lo in (("num_materials", 1), ("nside", 1), ("feature_dim", 1), ("index_bits", 1), ("hidden", 1),
                     ("hidden_layers", 0)):
        check_int(getattr(c, name), f"SharedNeuBRDF.{name}", lo)
    hpx.check_nside(c.nside, "SharedNeuBRDF.nside", power_of_two=True)
    if c.index_bits > 16:
        raise InputError(f"SharedNeuBRDF.index_bits: expected 1 .. 16, got {c.index_bits}")
    if c.interpolation not in ("idw", "uniform"):
        raise InputError(f"SharedNeuBRDF.interpolation: expected 'idw' or 'uniform', got {c.interpolation!r}")


@dataclass
class MaterialQuery(Query):
    """A Query whose row r asks material `material[r]` (N,) int64 of a shared model or a `JointSource`."""

    material: torch.Tensor | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        m = self.material
        if not isinstance(m, torch.Tensor) or m.dtype.is_floating_point or m.dtype == torch.bool:
            raise InputError("MaterialQuery.material: expected an integer tensor of material indices")
        check_shape(m, "MaterialQuery.material", (self.wi.shape[0],))

    def _map(self, fn) -> "MaterialQuery":
        kw = {f.name: None if getattr(self, f.name) is None else fn(f.name, getattr(self, f.name))
              for f in fields(self)}
        return MaterialQuery(**kw)

    def __getitem__(self, index) -> "MaterialQuery":
        return self._map(lambda name, t: t[index])

    def to(self, device=None, dtype=None) -> "MaterialQuery":
        return self._map(lambda name, t: t.to(device=device) if name == "material" else t.to(device, dtype))


@MODELS.register("shared-neubrdf")
class SharedNeuBRDF(LearnedMaterial):
    """t NeuBRDF materials with one shared MLP and codebook and one index grid each.

    `material(i)` is a Material view of material i. `eval(q)` evaluates each row of a `MaterialQuery` on its
    material, and a plain Query on the material selected with `select(i)` (0 by default).
    """

    name = "shared-neubrdf"
    paper = "NeuBRDF with codebooks shared across materials (Dou, Zheng et al. 2024, Sec. 3.3)"
    source_kinds = ("brdf-set",)
    can_sample = False
    Config = Config

    def __init__(self, config: Config | None = None, **kwargs) -> None:
        nn.Module.__init__(self)
        cfg = resolve_config(Config, config, kwargs, 'SharedNeuBRDF')
        _check_config(cfg)
        self.cfg = cfg
        n, t, k = cfg.nside, cfg.num_materials, cfg.feature_dim
        self.slots_per_material = 2 * hpx.hemisphere_size(n)
        self.grid = VQFeatures(t * self.slots_per_material, k, cfg.index_bits)
        self.mlp = MLP(2 * k, cfg.hidden, cfg.hidden_layers, 3, cfg.activation)
        self.register_buffer("level_i", torch.zeros(t, 12 * n * n, dtype=torch.int8))
        self.register_buffer("level_o", torch.zeros(t, 12 * n * n, dtype=torch.int8))
        self.register_buffer("vertex_dirs", hpx.vertex2vec(n, torch.arange(hpx.nvertices(n)), torch.float32),
                             persistent=False)
        self.active = 0

    @property
    def config(self) -> Config:
        return self.cfg

    def _check_index(self, i: int) -> int:
        t = self.cfg.num_materials
        if isinstance(i, bool) or not isinstance(i, int) or not 0 <= i < t:
            raise InputError(f"SharedNeuBRDF material index: expected an integer in [0, {t}), got {i!r}")
        return i

    def select(self, i: int) -> "SharedNeuBRDF":
        """Make material i the one a plain Query evaluates; returns self."""
        self.active = self._check_index(i)
        return self

    def material(self, i: int) -> "SharedMaterialView":
        """A Material view of material i (evaluates through this model; shares its parameters)."""
        return SharedMaterialView(self, self._check_index(i))

    # ------------------------------------------------------------------------------------- eval

    def _lookup(self, ids: torch.Tensor, w: torch.Tensor, south: bool) -> torch.Tensor:
        """Interpolated features (N, k) of directions w (N, 3) on the S+ (wi) or S- (mirrored wo) grid of
        materials ids (N,)."""
        n = self.cfg.nside
        d = hpx.hemisphere_direction(w, south)
        pix = hpx.vec2pix_unchecked(n, d)
        level = (self.level_o if south else self.level_i)[ids, pix].long()
        level = torch.minimum(level, hpx.grid_level_cap(n, south).to(pix.device)[pix])  # stay on the grid
        vid = hpx.ancestor_corner_vertices(n, pix, level)
        slots = (vid + hpx.south_grid_offset(n) if south else vid) + (ids * self.slots_per_material).unsqueeze(-1)
        feats = self.grid(slots)
        if self.cfg.interpolation == "uniform":
            return feats.mean(1)
        wts = hpx.idw_weights(d, self.vertex_dirs[vid].to(d.dtype))
        return (wts.unsqueeze(-1) * feats).sum(1)

    def _material_ids(self, q: Query) -> torch.Tensor:
        if isinstance(q, MaterialQuery):
            ids = q.material.to(q.device).long()
            t = self.cfg.num_materials
            if ids.numel() and (ids.min().item() < 0 or ids.max().item() >= t):
                raise InputError(f"MaterialQuery.material: indices must lie in [0, {t}) for this SharedNeuBRDF")
            return ids
        return torch.full((q.wi.shape[0],), self.active, dtype=torch.long, device=q.device)

    def eval(self, q: Query) -> torch.Tensor:
        """BRDF value (N, 3), linear RGB, cosine excluded, 0 below the horizon; rows of a MaterialQuery on
        their material, a plain Query on the selected one."""
        q.require("wo", who="SharedNeuBRDF.eval")
        ids = self._material_ids(q)
        wi, wo = q.wi.to(self.vertex_dirs.dtype), q.wo.to(self.vertex_dirs.dtype)
        x = torch.cat([self._lookup(ids, wi, False), self._lookup(ids, wo, True)], -1)
        f = torch.exp(self.mlp(x))
        f = torch.where(upper_hemisphere(q.wi, q.wo).unsqueeze(-1), f, torch.zeros_like(f))
        return f.to(q.dtype)

    @torch.no_grad()
    def init_from_targets(self, target: torch.Tensor) -> None:
        """Trainer hook: start at the per-channel median of `target` (N, 3) (all materials), as NeuBRDF."""
        if target.ndim != 2 or target.shape[1] != 3:
            raise InputError(f"SharedNeuBRDF.init_from_targets: expected targets (N, 3), got {tuple(target.shape)}")
        self.mlp.start_constant(target.median(0).values.clamp(min=1e-4).log())

    def eval_material(self, i: int, q: Query) -> torch.Tensor:
        """BRDF value (N, 3) of material i at the plain query q."""
        ids = torch.full((q.wi.shape[0],), self._check_index(i), dtype=torch.long, device=q.device)
        return self.eval(MaterialQuery(q.wi, q.wo, material=ids))

    def forward(self, q: Query) -> torch.Tensor:
        return self.eval(q)

    # -------------------------------------------------------------------------- pruning, freezing

    def prune(self, i: int, wi: torch.Tensor, wo: torch.Tensor) -> None:
        """Multi-resolution sparse index grids of material i from its supervised directions wi, wo (N, 3)
        (as `NeuBRDF.prune`)."""
        i = self._check_index(i)
        n = self.cfg.nside
        for south, w, label in ((False, wi, "wi"), (True, wo, "wo")):
            check_directions(w, f"SharedNeuBRDF.prune {label}")
            sup = hpx.supervised_pixels(n, hpx.hemisphere_direction(w, south))
            (self.level_o if south else self.level_i)[i].copy_(hpx.pruned_levels(n, sup).to(torch.int8))

    def freeze(self) -> None:
        """Freeze every material's vertex indices to integers (export / runtime)."""
        self.grid.freeze()

    # ------------------------------------------------------------------------------------ storage

    def size_bytes(self, precision: str = "fp16") -> int:
        """All t index grids (t 2n b bits) + the shared codebook and MLP (floats at `precision`)."""
        fb = float_bits(precision)
        return storage_bytes(self.grid.storage_bits(fb) + self.mlp.num_parameters() * fb)

    def size_bytes_per_material(self, precision: str = "fp16") -> float:
        """`size_bytes` / t: one index grid plus a 1 / t share of the codebook and the MLP."""
        return self.size_bytes(precision) / self.cfg.num_materials

    def flops(self) -> int:
        """Shared-MLP floating-point operations per evaluation (lookups not counted)."""
        return self.mlp.flops()


class SharedMaterialView(Material):
    """Material i of a SharedNeuBRDF (eval only; parameters stay in the shared model)."""

    can_sample = False

    def __init__(self, shared: SharedNeuBRDF, index: int) -> None:
        self.shared, self.index = shared, index
        self.name = f"shared-neubrdf[{index}]"

    def eval(self, q: Query) -> torch.Tensor:
        return self.shared.eval_material(self.index, q)

    def size_bytes(self, precision: str = "fp16") -> float:
        """Bytes attributable to this material: its index grid plus a 1 / t share of codebook and MLP."""
        return self.shared.size_bytes_per_material(precision)

    def flops(self) -> int:
        return self.shared.flops()

    def describe(self) -> str:
        return f"material {self.index} of a shared NeuBRDF of {self.shared.cfg.num_materials}"


# ------------------------------------------------------------------------------------ accounting

@dataclass
class SharingCost:
    """Bytes per material of t materials stored with one shared codebook and MLP vs as t separate NeuBRDFs."""

    shared_per_material: float
    """ceil((t 2n b + p k 2^b + p mlp) / 8) / t."""
    separate_per_material: int
    """ceil((2n b + p k 2^b + p mlp) / 8): a standalone NeuBRDF (`NeuBRDF.size_bytes`)."""

    @property
    def ratio(self) -> float:
        """separate / shared."""
        return self.separate_per_material / self.shared_per_material


def sharing_cost(cfg: Config, precision: str = "fp16") -> SharingCost:
    """Bytes per material of `cfg.num_materials` materials with and without sharing (no model is built).
    n = 6 nside^2 + 6 nside + 1 vertices per hemisphere grid; mlp = weights and biases of the 2k -> 3 MLP."""
    _check_config(cfg)
    p = float_bits(precision)
    slots = 2 * hpx.hemisphere_size(cfg.nside)
    dims = [2 * cfg.feature_dim] + [cfg.hidden] * cfg.hidden_layers + [3]
    mlp = sum(a * b + b for a, b in zip(dims[:-1], dims[1:]))
    shared_bits = p * cfg.feature_dim * 2 ** cfg.index_bits + p * mlp
    t = cfg.num_materials
    return SharingCost(shared_per_material=storage_bytes(t * slots * cfg.index_bits + shared_bits) / t,
                       separate_per_material=storage_bytes(slots * cfg.index_bits + shared_bits))


# ----------------------------------------------------------------------------------- clustering

def tabulate_rusinkiewicz(material: Material, resolution: int = 16, device=None) -> torch.Tensor:
    """log(1 + f) (3, R, R, R) of an isotropic material at cell centres of a Rusinkiewicz grid (phi_h = 0):
    theta_h = ((i + 0.5) / R)^2 pi / 2 (MERL's warp, dense near the peak), theta_d = (j + 0.5) / R pi / 2,
    phi_d = (k + 0.5) / R pi; 0 where a direction is below the horizon."""
    r = resolution
    kw = dict(dtype=torch.float32, device=device)
    th = ((torch.arange(r, **kw) + 0.5) / r) ** 2 * (math.pi / 2)
    td = (torch.arange(r, **kw) + 0.5) / r * (math.pi / 2)
    pd = (torch.arange(r, **kw) + 0.5) / r * math.pi
    th, td, pd = (g.reshape(-1) for g in torch.meshgrid(th, td, pd, indexing="ij"))
    wi, wo = rusinkiewicz_to_io(th, torch.zeros_like(th), td, pd)
    wi, wo = wi / wi.norm(dim=-1, keepdim=True), wo / wo.norm(dim=-1, keepdim=True)
    ok = upper_hemisphere(wi, wo)
    out = torch.zeros(th.shape[0], 3, **kw)
    with torch.no_grad():
        out[ok] = torch.log1p(material.eval(Query(wi[ok], wo[ok])).float().clamp(min=0))
    return out.T.reshape(3, r, r, r)


@dataclass
class Clustering:
    """Result of `cluster_materials`: labels (M,) cluster of each material, codes (M, code_dim) autoencoder
    bottleneck codes, reconstruction_mse the autoencoder's final training error (log(1 + f) units)."""

    labels: np.ndarray
    codes: np.ndarray
    reconstruction_mse: float
    groups: list[list[int]] = field(init=False)

    def __post_init__(self) -> None:
        self.groups = [sorted(np.flatnonzero(self.labels == c).tolist()) for c in np.unique(self.labels)]


def cluster_materials(materials: Sequence[Material], k: int, *, resolution: int = 16, code_dim: int = 8,
                      width: int = 16, steps: int = 500, lr: float = 3e-3, seed: int = 0,
                      device=None) -> Clustering:
    """Group `materials` into k clusters (paper Sec. 3.3): tabulate each (`tabulate_rusinkiewicz`), train a
    convolutional autoencoder (`neumat.nn.conv_autoencoder`) to reconstruct the tables, and run k-means
    (scikit-learn, 10 restarts, seeded) on the bottleneck codes."""
    from sklearn.cluster import KMeans

    materials = list(materials)
    if isinstance(k, bool) or not isinstance(k, int) or not 1 <= k <= len(materials):
        raise InputError(f"cluster_materials k: expected an integer in [1, {len(materials)}] (the number of "
                         f"materials), got {k!r}")
    for m in materials:
        if not isinstance(m, Material) or m.spatially_varying:
            raise InputError(f"cluster_materials: expected plain BRDF Materials, got {type(m).__name__}")
    volumes = torch.stack([tabulate_rusinkiewicz(m, resolution, device) for m in materials])
    ae = ConvAutoencoder(3, resolution, code_dim, width).to(volumes.device)
    losses = train_autoencoder(ae, volumes, steps=steps, lr=lr, seed=seed)
    with torch.no_grad():
        codes = ae.encode(volumes).cpu().numpy().astype(np.float64)
    labels = KMeans(n_clusters=k, n_init=10, random_state=seed).fit(codes).labels_
    return Clustering(labels=np.asarray(labels), codes=codes, reconstruction_mse=losses[-1])


# -------------------------------------------------------------------------------- joint training

class JointSource(Material):
    """The t source materials of a cluster as one Material answering `MaterialQuery`s row by row.
    `queries` names the base query sampler of each material for the "joint" sampler."""

    def __init__(self, sources: Sequence[Material], queries: str = "cosine") -> None:
        self.sources = list(sources)
        if not self.sources:
            raise InputError("JointSource: expected at least one source material")
        for s in self.sources:
            if not callable(getattr(s, "eval", None)) or getattr(s, "spatially_varying", False):
                raise InputError(f"JointSource: sources must be plain BRDF Materials, got {type(s).__name__}")
        QUERY_SAMPLERS.get(queries)  # unknown names fail here, with close matches
        self.queries = queries
        self.name = f"joint({len(self.sources)})"

    def eval(self, q: Query) -> torch.Tensor:
        if not isinstance(q, MaterialQuery):
            raise InputError("JointSource.eval: expected a MaterialQuery (rows tagged with material indices)")
        out = torch.zeros(q.wi.shape[0], 3, dtype=q.dtype, device=q.device)
        for i, s in enumerate(self.sources):
            rows = (q.material == i).nonzero().squeeze(-1)
            if rows.numel():
                out[rows] = s.eval(Query(q.wi[rows], q.wo[rows])).to(q.dtype)
        return out

    def describe(self) -> str:
        return f"joint source of {len(self.sources)} materials ({', '.join(_describe(s) for s in self.sources)})"


def _describe(m) -> str:
    return m.describe() if hasattr(m, "describe") else type(m).__name__


@QUERY_SAMPLERS.register("joint")
def joint_queries(source: Material, model=None):
    """Queries for a JointSource: each batch split evenly over the t materials, material i drawn by the
    source's base sampler for (source i, model.material(i))."""
    if not isinstance(source, JointSource):
        raise InputError(f"query sampler 'joint' needs a JointSource, got {type(source).__name__}")
    t = len(source.sources)
    views = [model.material(i) if isinstance(model, SharedNeuBRDF) else None for i in range(t)]
    base = [QUERY_SAMPLERS.get(source.queries)(s, v) for s, v in zip(source.sources, views)]

    def draw(n: int, generator: torch.Generator, device) -> MaterialQuery:
        counts = [n // t + (i < n % t) for i in range(t)]
        parts = [(i, base[i](c, generator, device)) for i, c in enumerate(counts) if c]
        wi = torch.cat([p.wi for _, p in parts])
        wo = torch.cat([p.wo for _, p in parts])
        ids = torch.cat([torch.full((p.wi.shape[0],), i, dtype=torch.long, device=p.wi.device) for i, p in parts])
        return MaterialQuery(wi, wo, material=ids)

    return draw


def fit_shared(model: SharedNeuBRDF, sources: Sequence[Material], recipe: Recipe | None = None, *,
               queries: str | None = None, **fit_kwargs):
    """Train the shared MLP, codebook and all t index grids of `model` jointly on `sources` (one per material)
    with the shared trainer. recipe defaults to NeuBRDF's; `queries` (default: the recipe's) is the base
    sampler per material; other keywords go to `neumat.fit.trainer.fit`. Returns its FitResult."""
    from neumat.fit.trainer import fit

    if not isinstance(model, SharedNeuBRDF):
        raise InputError(f"fit_shared: expected a SharedNeuBRDF, got {type(model).__name__}")
    sources = list(sources)
    if len(sources) != model.cfg.num_materials:
        raise InputError(f"fit_shared: the model holds {model.cfg.num_materials} materials, got "
                         f"{len(sources)} sources")
    recipe = replace(recipe if recipe is not None else recipe_for("neubrdf"))
    joint = JointSource(sources, queries or recipe.queries)
    return fit(model, joint, replace(recipe, queries="joint"), **fit_kwargs)


def fit_clusters(materials: Sequence[Material], k: int, config: dict | None = None,
                 recipe: Recipe | None = None, *, clustering: Clustering | None = None,
                 cluster_kwargs: dict | None = None, **fit_kwargs) -> list[tuple[list[int], SharedNeuBRDF]]:
    """The paper's pipeline: cluster `materials` into k groups (or use `clustering`), then fit one
    SharedNeuBRDF (fields `config`, num_materials set per group) per group with `fit_shared`.
    Returns [(material indices of the group, fitted model)]."""
    materials = list(materials)
    clustering = clustering or cluster_materials(materials, k, **(cluster_kwargs or {}))
    out = []
    for group in clustering.groups:
        model = SharedNeuBRDF(**{**(config or {}), "num_materials": len(group)})
        fit_shared(model, [materials[i] for i in group], recipe, **fit_kwargs)
        out.append((group, model))
    return out
