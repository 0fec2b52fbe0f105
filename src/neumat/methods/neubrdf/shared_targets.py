"""Training of NeuBRDF with codebooks shared across materials (Dou et al. 2024, Sec. 3.3): clustering the
materials (convolutional autoencoder + k-means, `cluster_materials`) and the joint fit of one
`neumat.methods.neubrdf.shared_model.SharedNeuBRDF` per cluster (`fit_shared`, `fit_clusters`).

Joint training runs through the one trainer: `fit(model, [source_0, ..., source_t-1])` (recipe
`neumat.methods.neubrdf.shared_train`) wraps the t sources in a `JointSource`, which answers a `MaterialQuery`
row by row from the material each row asks, and draws batches with the "joint" query sampler (an equal share
of each batch per material, drawn by that material's base sampler).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
import torch

from neumat.core.coords import rusinkiewicz_to_io
from neumat.core.errors import InputError
from neumat.core.material import Material, describe_source, upper_hemisphere
from neumat.core.query import Query
from neumat.methods.neubrdf.shared_model import MaterialQuery, SharedNeuBRDF
from neumat.nn.conv_autoencoder import ConvAutoencoder, train_autoencoder
from neumat.fit.query_samplers import QUERY_SAMPLERS
from neumat.fit.recipe import Recipe
from neumat.fit.method import recipe_for, typed_options


# ----------------------------------------------------------------------------------- clustering

def tabulate_rusinkiewicz(material: Material, resolution: int, device=None) -> torch.Tensor:
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
    bottleneck codes, reconstruction_mse the autoencoder's final training error (log(1 + f) units), errors (M,)
    each material's reconstruction MSE by the trained autoencoder (same units; None when not computed)."""

    labels: np.ndarray
    codes: np.ndarray
    reconstruction_mse: float
    errors: np.ndarray | None = None
    groups: list[list[int]] = field(init=False)

    def __post_init__(self) -> None:
        self.groups = [sorted(np.flatnonzero(self.labels == c).tolist()) for c in np.unique(self.labels)]


def cluster_materials(materials: Sequence[Material], k: int, *, resolution: int | None = None,
                      code_dim: int | None = None, width: int | None = None, steps: int | None = None,
                      lr: float | None = None, seed: int | None = None, device=None) -> Clustering:
    """Group `materials` into k clusters (paper Sec. 3.3): tabulate each (`tabulate_rusinkiewicz`), train a
    convolutional autoencoder (`neumat.nn.conv_autoencoder`) to reconstruct the tables, and run k-means
    (scikit-learn, 10 restarts, seeded) on the bottleneck codes. Defaults: the shared-neubrdf recipe's options
    cluster_resolution, cluster_code_dim, cluster_width, cluster_steps, cluster_lr, and its seed."""
    from sklearn.cluster import KMeans

    recipe = recipe_for("shared-neubrdf")
    opts = typed_options("shared-neubrdf", recipe.options)
    resolution = opts.cluster_resolution if resolution is None else resolution
    code_dim = opts.cluster_code_dim if code_dim is None else code_dim
    width = opts.cluster_width if width is None else width
    steps = opts.cluster_steps if steps is None else steps
    lr = opts.cluster_lr if lr is None else lr
    seed = recipe.seed if seed is None else seed

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
        errors = (ae(volumes) - volumes).square().mean(dim=(1, 2, 3, 4)).cpu().numpy().astype(np.float64)
    labels = KMeans(n_clusters=k, n_init=10, random_state=seed).fit(codes).labels_
    return Clustering(labels=np.asarray(labels), codes=codes, reconstruction_mse=losses[-1], errors=errors)


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
        return f"joint source of {len(self.sources)} materials ({', '.join(describe_source(s) for s in self.sources)})"


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
    with the trainer: `fit(model, list(sources), recipe, queries=queries, ...)` (recipe default: the
    shared-neubrdf recipe, NeuBRDF's defaults; `queries`, default the recipe's, is the base sampler per
    material). Other keywords go to `neumat.fit.trainer.fit`. Returns its FitResult."""
    from neumat.fit.trainer import fit

    if not isinstance(model, SharedNeuBRDF):
        raise InputError(f"fit_shared: expected a SharedNeuBRDF, got {type(model).__name__}")
    return fit(model, list(sources), recipe, queries=queries, **fit_kwargs)


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


def joint_source(ctx_source, num_materials: int, queries: str) -> JointSource:
    """The JointSource of a shared fit's source: a list / tuple of t Materials (or a JointSource), checked
    against the model's t materials; `queries` is each material's base sampler."""
    if isinstance(ctx_source, JointSource):
        joint = ctx_source
    elif isinstance(ctx_source, (list, tuple)):
        if queries == "joint":
            raise InputError("shared-neubrdf: the query sampler names the base sampler of each material (e.g. "
                             "'cosine'), not 'joint' (the fit builds the joint sampler itself)")
        joint = JointSource(ctx_source, queries)
    else:
        raise InputError(f"shared-neubrdf: the source must be a list of Materials, one per material of the model, "
                         f"got {type(ctx_source).__name__}")
    if len(joint.sources) != num_materials:
        raise InputError(f"shared-neubrdf: the model holds {num_materials} materials, got "
                         f"{len(joint.sources)} sources")
    return joint
