"""NeuBRDF with neural reflectance primitives shared across materials (Dou et al. 2024, Sec. 3.3).

A cluster of t similar materials shares one MLP and one codebook D (2^b, k); each material keeps only its
own spherical index grid (2 n b-bit indices). The clusters come from a convolutional autoencoder trained to
reconstruct tabulated reflectance, then k-means on its bottleneck codes; the shared modules and the t index
grids are trained jointly. Both are training code, in the fit package: methods/neubrdf/shared_targets.py
(`cluster_materials`, `fit_shared`, `fit_clusters`) and the recipe methods/neubrdf/shared_train.py.

A `MaterialQuery` carries, per row, the index of the material it asks; the model evaluates every row on
that material's index grid, so one training batch mixes all materials (`fit(model, [source_0, ...])`).

Storage: all index grids live in one `VQFeatures` of t * 2n vertices, whose storage formula is exactly
t 2n b + p k 2^b bits; see `sharing_cost` for the bytes per material with and without sharing.
"""
from __future__ import annotations

from dataclasses import dataclass, fields, replace
from types import SimpleNamespace

import torch
from torch import nn

from neumat.core.checks import check_directions, check_int, check_memory, check_shape
from neumat.core.config import bounded, check_bounds, resolve_config
from neumat.core.errors import InputError
from neumat.core.material import Material, zero_below_horizon
from neumat.core.query import Query
from neumat.core.tensors import derived_from
from neumat.models.base import LearnedMaterial
from neumat.methods.neubrdf.model import (DIRECTION_INPUTS, capped_levels, check_direction_inputs, direction_inputs,
                                   quantize_dense_grid, quantized_state, regridded_state, shipped_state,
                                   unpack_levels, used_slot_mask)
from neumat.nn import cpu_kernels
from neumat.nn import healpix as hpx
from neumat.nn.codebook import DenseFeatures, VQFeatures, float_bits, storage_bytes
from neumat.nn.mlp import MLP, log_median
from neumat.nn.row_adam import RowAdam, grid_optimizer


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
    """Hidden activation of the shared MLP (as NeuBRDF's; see `neumat.methods.neubrdf.model.Config`)."""
    interpolation: str = "idw"
    """Corner weights: "idw" (inverse great-circle distance, training) or "uniform" (1/4, runtime)."""
    direction_inputs: str = "none"
    """Extra inputs of the shared MLP, as NeuBRDF's (`neumat.methods.neubrdf.model.Config.direction_inputs`): "none"
    (the paper), "hd" or "hd_warp" (6 inputs from the half and difference vectors, our extension)."""
    features: str = "vq"
    """Vertex feature storage: "vq" (indices into the shared codebook, the paper) or "dense" (k floats per vertex
    and material: the warm-up of a fit that ends with `quantize_from_dense`, see
    `neumat.methods.neubrdf.shared_train`)."""
    index_lr_scale: float = bounded(10.0, gt=0)
    """Learning-rate factor of the index logits (as `neumat.methods.neubrdf.model.Config.index_lr_scale`)."""


def _check_config(c: Config) -> None:
    for f in fields(c):
        check_bounds(f, getattr(c, f.name), f"SharedNeuBRDF.{f.name}")
    for name, lo in (("num_materials", 1), ("nside", 1), ("feature_dim", 1), ("index_bits", 1), ("hidden", 1),
                     ("hidden_layers", 0)):
        check_int(getattr(c, name), f"SharedNeuBRDF.{name}", lo)
    hpx.check_nside(c.nside, "SharedNeuBRDF.nside", power_of_two=True)
    if c.index_bits > 16:
        raise InputError(f"SharedNeuBRDF.index_bits: expected 1 .. 16, got {c.index_bits}")
    if c.interpolation not in ("idw", "uniform"):
        raise InputError(f"SharedNeuBRDF.interpolation: expected 'idw' or 'uniform', got {c.interpolation!r}")
    check_direction_inputs(c.direction_inputs, "SharedNeuBRDF")
    if c.features not in ("vq", "dense"):
        raise InputError(f"SharedNeuBRDF.features: expected 'vq' or 'dense', got {c.features!r}")
    slot = 4 * (2 ** c.index_bits if c.features == "vq" else c.feature_dim)  # float32 index logits / features
    check_memory(hpx.grid_bytes(c.nside, c.num_materials, slot),
                 f"SharedNeuBRDF nside={c.nside}, index_bits={c.index_bits}, {c.num_materials} materials")


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


def _after_load(module: "SharedNeuBRDF", keys) -> None:
    """`load_state_dict`'s post-hook: the loaded pruning levels are checked (a function, not a lambda, so that a
    model pickles)."""
    module._check_levels()


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
        rows = t * self.slots_per_material
        self.grid = VQFeatures(rows, k, cfg.index_bits) if cfg.features == "vq" else DenseFeatures(rows, k)
        self.mlp = MLP(2 * k + DIRECTION_INPUTS[cfg.direction_inputs], cfg.hidden, cfg.hidden_layers, 3,
                       cfg.activation)
        self.register_buffer("level_i", torch.zeros(t, 12 * n * n, dtype=torch.int8))
        self.register_buffer("level_o", torch.zeros(t, 12 * n * n, dtype=torch.int8))
        self.register_load_state_dict_post_hook(_after_load)
        self.register_buffer("vertex_dirs", hpx.vertex2vec(n, torch.arange(hpx.nvertices(n)), torch.float32),
                             persistent=False)
        self.active = 0
        self._runtime = False
        self.register_state_dict_post_hook(shipped_state)
        self.register_load_state_dict_pre_hook(unpack_levels)
        self.register_load_state_dict_pre_hook(regridded_state)
        self.register_load_state_dict_pre_hook(quantized_state)

    @property
    def config(self) -> Config:
        return self.cfg

    def _check_levels(self) -> None:
        """Refuse loaded pruning levels outside the hierarchy (`hpx.check_levels`)."""
        for name in ("level_i", "level_o"):
            hpx.check_levels(getattr(self, name), self.cfg.nside, f"SharedNeuBRDF.{name}")

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
        return self._lookup_both(ids, ((w, south),))[0]

    def _lookup_both(self, ids: torch.Tensor, dirs, kernel_pixels: bool = False) -> list[torch.Tensor]:
        """The interpolated features (N, k) of each (w (N, 3), south) of `dirs` for materials ids (N,), with one
        feature-grid call for all corners (a VQ grid runs its straight-through step once, as NeuBRDF's);
        `kernel_pixels`: see `_corners`."""
        pruned = self.pruned
        corners = [self._corners(ids, w, south, pruned, kernel_pixels) for w, south in dirs]
        feats = self.grid(torch.cat([slots for _, slots, _ in corners]))  # (sum N, 4, k)
        out = []
        for (d, _, vid), f in zip(corners, feats.split([slots.shape[0] for _, slots, _ in corners])):
            if self.cfg.interpolation == "uniform":
                out.append(f.mean(1))
            else:
                out.append((hpx.idw_weights(d, self.vertex_dirs[vid].to(d.dtype)).unsqueeze(-1) * f).sum(1))
        return out

    def _corners(self, ids: torch.Tensor, w: torch.Tensor, south: bool, pruned: bool, kernel_pixels: bool = False):
        """(the direction looked up (N, 3), grid slots (N, 4), vertex ids (N, 4)) of the corners read for w (N, 3)
        on material ids' S+ or, mirrored, S- grid: at each pixel's pruning level, capped to stay on the grid; the
        corners from `_corner_table`. With `kernel_pixels` (evaluation) the pixels come from the C kernels' lookup
        where it applies (float32 on the CPU; as NeuBRDF's kernel, a direction exactly on a pixel edge may fall on
        the other side than torch's lookup puts it: regridding, which reads at vertices, keeps torch's)."""
        n = self.cfg.nside
        d = hpx.hemisphere_direction(w, south)
        fast = kernel_pixels and cpu_kernels.usable(d)
        pix = cpu_kernels.ring_pixels(n, d).long() if fast else hpx.vec2pix_unchecked(n, d)
        slots, vid = self._corner_table(south, pruned)
        at = (ids, pix) if pruned else (0, pix)
        return d, slots[at] + (ids * self.slots_per_material).unsqueeze(-1), vid[at]

    def _corner_table(self, south: bool, pruned: bool) -> tuple[torch.Tensor, torch.Tensor]:
        """(slots, vertex ids), each (t or, unpruned, 1, 12 N_side^2, 4), of every ring pixel's corners on each
        material's S+ or S- grid at its capped pruning level: derived from the levels once, instead of the HEALPix
        corner arithmetic on every lookup (three quarters of a call of one query)."""
        levels, n = self.level_o if south else self.level_i, self.cfg.nside

        def make() -> torch.Tensor:
            pix = torch.arange(12 * n * n, device=levels.device)
            if not pruned:
                return torch.stack(hpx.pixel_corner_slots(n, pix, south))[:, None]
            level = torch.minimum(levels.long(), hpx.grid_level_cap(n, south).to(pix.device)[pix])
            return torch.stack([torch.stack(hpx.pixel_corner_slots(n, pix, south, level[m]))
                                for m in range(len(level))], 1)
        table = derived_from(self, f"corners_{int(south)}_{int(pruned)}_{n}", [levels], make, optimised=False)
        return table[0], table[1]

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
        fast = self._kernel_eval(q)
        if fast is not None:
            return fast
        ids = self._material_ids(q)
        wi, wo = q.wi.to(self.vertex_dirs.dtype), q.wo.to(self.vertex_dirs.dtype)
        parts = self._lookup_both(ids, ((wi, False), (wo, True)), kernel_pixels=True)
        if self.cfg.direction_inputs != "none":
            parts.append(direction_inputs(self.cfg.direction_inputs, wi, wo))
        f = torch.exp(self.mlp(torch.cat(parts, -1)))
        f = zero_below_horizon(f, q.wi, q.wo)
        return f.to(q.dtype)

    def _kernel_eval(self, q: Query) -> torch.Tensor | None:
        """`eval` as one fused C call (`neumat.nn.cpu_kernels.neubrdf_idw_eval`; the same values within float32
        rounding), or None where it does not apply: autograd, other dtypes or devices, uniform corner weights, an
        activation the kernels lack, no compiler."""
        if self.cfg.interpolation != "idw" or not cpu_kernels.usable(q.wi, q.wo, self.vertex_dirs, owner=self):
            return None
        k = cpu_kernels.prepared(self, self._kernel_bundle)
        if k is None:
            return None
        ids = self._material_ids(q) if isinstance(q, MaterialQuery) else None
        n = self.cfg.nside
        return cpu_kernels.neubrdf_idw_eval(k.mlp, q.wi, q.wo, ids, self.active, n, k.corners,
                                            self.slots_per_material, hpx.south_grid_offset(n), k.vertex_dirs,
                                            k.table, k.bias, k.first, k.columns, self.cfg.direction_inputs == "hd_warp")

    def _kernel_bundle(self) -> SimpleNamespace | None:
        """What `_kernel_eval` reads: the first layer applied to every slot of every material (S+ slots by its wi
        columns, S- slots by its wo columns), its bias and direction columns, the rest of the MLP packed, each
        pixel's corner vertices (int32, per material where pruned) and the vertex directions; None where the kernels
        lack the activations."""
        net, c = self.mlp.net, self.cfg
        first = cpu_kernels.activation_code(net[1]) if len(net) >= 3 else None
        mlp = None if first is None else cpu_kernels.PackedMLP.pack(list(net)[2:])
        if mlp is None:
            return None
        k, h = c.feature_dim, hpx.hemisphere_size(c.nside)
        feats = self.grid(torch.arange(self.grid.num_vertices, device=self.vertex_dirs.device)).float()
        feats = feats.view(c.num_materials, 2, h, k)
        weight = net[0].weight.detach().float()
        table = torch.stack([feats[:, 0] @ weight[:, :k].t(), feats[:, 1] @ weight[:, k:2 * k].t()], 1)
        extra = DIRECTION_INPUTS[c.direction_inputs]
        pruned = self.pruned
        corners = tuple(self._corner_table(south, pruned)[1].to(torch.int32).contiguous() for south in (False, True))
        return SimpleNamespace(first=first, mlp=mlp, table=table.reshape(-1, weight.shape[0]).contiguous(),
                               bias=net[0].bias.detach().float().contiguous(), corners=corners,
                               vertex_dirs=self.vertex_dirs.float().contiguous(),
                               columns=weight[:, -extra:] if extra else None)

    @torch.no_grad()
    def init_from_targets(self, target: torch.Tensor) -> None:
        """Trainer hook: start at the per-channel median of `target` (N, 3) (all materials), as NeuBRDF."""
        if target.ndim != 2 or target.shape[1] != 3:
            raise InputError(f"SharedNeuBRDF.init_from_targets: expected targets (N, 3), got {tuple(target.shape)}")
        self.mlp.start_constant(log_median(target))

    def eval_material(self, i: int, q: Query) -> torch.Tensor:
        """BRDF value (N, 3) of material i at the plain query q."""
        ids = torch.full((q.wi.shape[0],), self._check_index(i), dtype=torch.long, device=q.device)
        return self.eval(MaterialQuery(q.wi, q.wo, material=ids))

    def forward(self, q: Query) -> torch.Tensor:
        return self.eval(q)

    def optimizer(self, lr: float, betas: tuple[float, float] = (0.9, 0.999), eps: float = 1e-8) -> RowAdam:
        """The optimiser to train this model with (the trainer's hook), as NeuBRDF's: the VQ index logits of all
        materials get sparse row gradients, updated only on the vertices of each batch, at `Config.index_lr_scale` times
        the rate (a dense Adam step over the t x 2n x 2^b logits cost 0.45 of 1.1 s per step of 8192 queries for
        two materials at N_side 64)."""
        return grid_optimizer(self, self.grid, lr, betas, eps, self.cfg.index_lr_scale)

    # ------------------------------------------------------------- dense warm-up, coarse to fine

    def grid_rows(self, nside: int) -> int:
        """Slots of all t feature grids at `nside` (t x 2n)."""
        return self.cfg.num_materials * 2 * hpx.hemisphere_size(nside)

    @property
    def pruned(self) -> bool:
        """Whether `prune` made some pixel of some material look up an ancestor level (kept while the levels are
        unchanged: two scans of t x 12 N_side^2 levels were a sixth of a call of one query)."""
        return bool(derived_from(self, "pruned", [self.level_i, self.level_o],
                                 lambda: (self.level_i != 0).any() | (self.level_o != 0).any(), optimised=False))

    def used_slots(self) -> torch.Tensor:
        """Mask (t x 2n,) of the slots some pixel of their material's (pruned) grids reads."""
        n, pruned = self.cfg.nside, self.pruned
        masks = [used_slot_mask(n, (capped_levels(n, self.level_i[m], False), capped_levels(n, self.level_o[m], True))
                                if pruned else None, self.level_i.device)
                 for m in range(self.cfg.num_materials)]
        return torch.cat(masks)

    @torch.no_grad()
    def quantize_from_dense(self, index_bits: int | None = None, iterations: int = 25, margin: float = 1.0,
                            seed: int = 0, candidates: int = 0,
                            weights: torch.Tensor | None = None) -> "SharedNeuBRDF":
        """End of a dense warm-up, as `NeuBRDF.quantize_from_dense`: the shared codebook is the k-means of the used
        slots' features of ALL t materials (`neumat.nn.codebook_kmeans.vq_from_dense`), each slot's logits start on
        its nearest codeword (its K nearest only with `candidates` K), and `Config.features` becomes "vq". Returns
        self; build the optimiser again afterwards."""
        return quantize_dense_grid(self, "SharedNeuBRDF.quantize_from_dense", index_bits, iterations=iterations,
                                   margin=margin, seed=seed, candidates=candidates, weights=weights)

    def _use_vq_grid(self, vq: VQFeatures) -> None:
        """Install the VQ grid `vq` (this grid's rows); `Config.features` becomes "vq" with vq's index bits."""
        self.grid = vq
        self.cfg = replace(self.cfg, features="vq", index_bits=vq.bits)

    @torch.no_grad()
    def regrid(self, nside: int) -> "SharedNeuBRDF":
        """Coarse to fine, as `NeuBRDF.regrid`: every material's grids become dense grids at `nside` holding this
        model's interpolated features at the new slots' directions (`Config.nside` becomes `nside`, features
        "dense"; the MLP is kept). Not for pruned grids. Returns self; build the optimiser again."""
        nside = hpx.check_nside(nside, "SharedNeuBRDF.regrid nside", power_of_two=True)
        if self.pruned:
            raise InputError("SharedNeuBRDF.regrid: a pruned grid cannot be re-sampled (prune after regridding)")
        new_cfg = replace(self.cfg, nside=nside, features="dense")
        _check_config(new_cfg)
        dirs, h = hpx.grid_slot_directions(nside).to(self.vertex_dirs), hpx.hemisphere_size(nside)
        feats = []
        for m in range(self.cfg.num_materials):
            ids = torch.full((h,), m, dtype=torch.long, device=dirs.device)
            feats += [self._lookup(ids, dirs[:h], False), self._lookup(ids, dirs[h:], True)]
        self._set_dense_grid(new_cfg, torch.cat(feats))
        return self

    def _set_dense_grid(self, cfg: Config, feats: torch.Tensor) -> None:
        """Install dense grids at cfg.nside holding `feats` (t x 2n, k), and the buffers of that size."""
        device, n, t = self.level_i.device, cfg.nside, cfg.num_materials
        self.grid = DenseFeatures.holding(feats.to(device), next(self.mlp.parameters()).requires_grad)
        self.cfg = cfg
        self.slots_per_material = 2 * hpx.hemisphere_size(n)
        self.level_i = torch.zeros(t, 12 * n * n, dtype=torch.int8, device=device)
        self.level_o = torch.zeros(t, 12 * n * n, dtype=torch.int8, device=device)
        self.vertex_dirs = hpx.vertex2vec(n, torch.arange(hpx.nvertices(n)), torch.float32).to(self.vertex_dirs)

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

    @property
    def is_runtime(self) -> bool:
        """Whether `runtime()` is in effect (model files record it and re-enter it on load)."""
        return self._runtime

    @torch.no_grad()
    def runtime(self) -> "SharedNeuBRDF":
        """The shipped form: frozen indices and floats rounded to fp16; its `state_dict` stores them packed
        and as fp16, and the pruning levels packed (`neumat.methods.neubrdf.model.shipped_state`), instead of the
        t x 2n x 2^b float logits of training. The corner weights stay as configured (`interpolation`).
        Returns self, in eval mode."""
        self.freeze()
        for p in self.parameters():
            p.copy_(p.half())
        self._runtime = True
        return self.train(False)

    def train(self, mode: bool = True) -> "SharedNeuBRDF":
        """torch train / inference switch; training leaves runtime mode (the indices stay frozen)."""
        if mode:
            self._runtime = False
        return super().train(mode)

    @property
    def level_bits(self) -> int:
        """Bits of a stored pruning level (levels run from 0 to log2 N_side)."""
        return max(1, (self.cfg.nside.bit_length() - 1).bit_length())

    # ------------------------------------------------------------------------------------ storage

    def size_bytes(self, precision: str = "fp16") -> int:
        """All t index grids (t 2n b bits) + the shared codebook and MLP (floats at `precision`). The runtime
        model file also holds the pruning levels, packed (t x 2 x 12 N_side^2 x `level_bits` bits)."""
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
    n = 6 nside^2 + 6 nside + 1 vertices per hemisphere grid; mlp = weights and biases of the 2k (+ 6 direction
    inputs) -> 3 MLP."""
    _check_config(cfg)
    p = float_bits(precision)
    slots = 2 * hpx.hemisphere_size(cfg.nside)
    dims = [2 * cfg.feature_dim + DIRECTION_INPUTS[cfg.direction_inputs]] + [cfg.hidden] * cfg.hidden_layers + [3]
    mlp = sum(a * b + b for a, b in zip(dims[:-1], dims[1:]))
    shared_bits = p * cfg.feature_dim * 2 ** cfg.index_bits + p * mlp
    t = cfg.num_materials
    return SharingCost(shared_per_material=storage_bytes(t * slots * cfg.index_bits + shared_bits) / t,
                       separate_per_material=storage_bytes(slots * cfg.index_bits + shared_bits))
