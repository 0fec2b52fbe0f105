"""NeuBRDF (Dou, Zheng et al., CVPR 2024): HEALPix spherical index grids for wi and wo, a codebook of
neural reflectance primitives, a tiny MLP; optional neural-texture plug-in for spatially varying
materials and BTFs.

f(wi, wo[, uv]) = exp(m([psi(wi; S+), psi(wo_mirrored; S-)[, phi(uv; T)]]))      (paper Eq. 1, 3, 4)

psi interpolates the features of the 4 corner vertices of the HEALPix pixel that holds the direction,
with normalised inverse great-circle-distance weights (training) or 1/4 each (runtime). `wi` is looked
up on the north grid S+, `wo` mirrored to (pi - theta, phi) on the south grid S-; see `neumat.nn.healpix`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from types import SimpleNamespace

import torch
from torch import nn

from neumat.core.checks import check_directions, check_int, check_memory
from neumat.core.config import bounded, check_bounds, resolve_config
from neumat.core.errors import InputError
from neumat.core.material import zero_below_horizon
from neumat.core.query import Query
from neumat.core.tensors import cached_tensor, inference_call, rows_per_slice
from neumat.models.base import LearnedMaterial
from neumat.methods.baselines.nbrdf import NBRDF
from neumat.nn import cpu_kernels
from neumat.nn import healpix as hpx
from neumat.nn.codebook import DenseFeatures, LowBitFeatures, VQFeatures, float_bits, storage_bytes
from neumat.nn.codebook_kmeans import vq_from_dense
from neumat.nn.latent_texture import bilinear, trilinear
from neumat.nn.mlp import MLP, log_median
from neumat.nn.packing import pack_bits, unpack_bits
from neumat.nn.row_adam import RowAdam, grid_optimizer

#: values of `Config.direction_inputs` and the number of MLP inputs each adds
DIRECTION_INPUTS = {"none": 0, "hd": 6, "hd_warp": 6}


def check_direction_inputs(kind: str, who: str) -> None:
    """Refuse a `Config.direction_inputs` value that is not one of `DIRECTION_INPUTS`, naming `who`."""
    if kind not in DIRECTION_INPUTS:
        raise InputError(f"{who}.direction_inputs: expected one of {', '.join(map(repr, DIRECTION_INPUTS))}, "
                         f"got {kind!r}")


def direction_inputs(kind: str, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
    """The extra MLP inputs (N, 6) of `Config.direction_inputs` `kind` ("hd" or "hd_warp") of directions wi, wo
    (N, 3). "hd": NBRDF's (hx, hy, hz, dx, dy, dz) (`NBRDF.encode`). "hd_warp": the same with (hx, hy), of length
    sin theta_h, rescaled to length sqrt(theta_h / (pi / 2)), MERL's coordinate of theta_h: a highlight 1 degree
    wide spans 0.1 of that input instead of 0.017 of sin theta_h."""
    hd = NBRDF.encode(wi, wo)
    if kind == "hd":
        return hd
    st = hd[:, :2].norm(dim=-1, keepdim=True)
    radius = (torch.atan2(st, hd[:, 2:3]) / (0.5 * math.pi)).sqrt()
    return torch.cat([hd[:, :2] * torch.where(st > 0, radius / st.clamp(min=1e-30), 0.0), hd[:, 2:]], -1)


@dataclass
class Config:
    """NeuBRDF hyper-parameters; defaults are the paper's (Sec. 4)."""

    nside: int = 64
    """HEALPix resolution N_side of the grids (a power of two: pruning uses the nested hierarchy)."""
    feature_dim: int = 16
    """k, dimension of a neural reflectance primitive (codebook row / vertex feature)."""
    index_bits: int = 9
    """b, bits of a vertex's codebook index; the codebook has 2^b rows."""
    hidden: int = 64
    """Neurons per hidden MLP layer."""
    hidden_layers: int = 2
    """Number of hidden MLP layers."""
    activation: str = "leaky_relu"
    """Hidden activation of the MLP (the paper does not name one). Leaky ReLU (slope 0.01): ReLU units died on
    dark measured materials, SiLU evaluates slower (src/neumat/methods/neubrdf/NOTES.md, "Config.activation")."""
    features: str = "vq"
    """Vertex feature storage: "vq" (codebook indices, the paper), "dense" (floats per vertex) or
    "lowbit" (per-vertex features quantised to `lowbit_bits` bits); the last two are the Table 4 ablations."""
    lowbit_bits: int = 4
    """Bits per feature value in "lowbit" mode."""
    interpolation: str = "idw"
    """Corner weights: "idw" (normalised inverse great-circle distance, training) or "uniform" (1/4, runtime)."""
    runtime_interpolation: str = "uniform"
    """Corner weights of the runtime form (`NeuBRDF.runtime`): "uniform", the paper's 1/4 (one feature per pixel:
    two table reads per evaluation), or "idw", the training form's weights (8 reads and 8 weights per
    evaluation), which keep specular peaks narrower than a pixel
    (src/neumat/methods/neubrdf/NOTES.md, "Config.runtime_interpolation")."""
    texture_height: int = 0
    """h of the neural texture T (h x w x c) for spatially varying materials; 0 without texture."""
    texture_width: int = 0
    """w of the neural texture T."""
    texture_channels: int = 0
    """c of the neural texture T; 0 disables the texture plug-in."""
    texture_levels: int = 1
    """Mip levels of T (level l is h / 2^l x w / 2^l, each learned); Query.lod blends them trilinearly."""
    direction_inputs: str = "none"
    """Extra MLP inputs besides the features: "none" (the paper: the MLP sees the interpolated features only),
    "hd", our extension: the Rusinkiewicz half and difference vectors (hx, hy, hz, dx, dy, dz) of (wi, wo),
    NBRDF's 6 inputs (`NBRDF.encode`), appended last, 6 x hidden more MLP weights; or "hd_warp": the same with
    the half vector's (hx, hy) warped to MERL's sqrt(theta_h) coordinate (`direction_inputs`). Why: the MLP,
    given h, places highlights finer than 2^b codewords can (src/neumat/methods/neubrdf/NOTES.md,
    "Config.direction_inputs")."""
    pruned_ancestor_fraction: float = bounded(0.5, gt=0, le=1)
    """Share of training lookups in supervised pixels of a pruned grid made at an ancestor level (`NeuBRDF.prune`)."""
    index_lr_scale: float = bounded(10.0, gt=0)
    """Learning rate of the VQ index logits relative to the recipe's (the trainer honours a param group's
    "lr_scale"); 10 gave the lowest held-out error (src/neumat/methods/neubrdf/NOTES.md, "NeuBRDF.index_lr_scale")."""


def _check_config(c: Config) -> None:
    for f in fields(c):
        check_bounds(f, getattr(c, f.name), f"NeuBRDF.{f.name}")
    for name in ("nside", "feature_dim", "index_bits", "hidden", "lowbit_bits", "texture_levels"):
        check_int(getattr(c, name), f"NeuBRDF.{name}")
    for name in ("hidden_layers", "texture_height", "texture_width", "texture_channels"):
        check_int(getattr(c, name), f"NeuBRDF.{name}", 0)
    hpx.check_nside(c.nside, "NeuBRDF.nside", power_of_two=True)
    if c.index_bits > 16:
        raise InputError(f"NeuBRDF.index_bits: expected 1 .. 16, got {c.index_bits}")
    if c.lowbit_bits > 8:
        raise InputError(f"NeuBRDF.lowbit_bits: expected 1 .. 8, got {c.lowbit_bits}")
    if c.features not in ("vq", "dense", "lowbit"):
        raise InputError(f"NeuBRDF.features: expected 'vq', 'dense' or 'lowbit', got {c.features!r}")
    for name in ("interpolation", "runtime_interpolation"):
        if getattr(c, name) not in ("idw", "uniform"):
            raise InputError(f"NeuBRDF.{name}: expected 'idw' or 'uniform', got {getattr(c, name)!r}")
    check_direction_inputs(c.direction_inputs, "NeuBRDF")
    if c.texture_channels and (c.texture_height < 1 or c.texture_width < 1):
        raise InputError("NeuBRDF.texture_height/texture_width: expected >= 1 with texture_channels > 0")
    if c.texture_channels and min(c.texture_height, c.texture_width) >> (c.texture_levels - 1) < 1:
        raise InputError(f"NeuBRDF.texture_levels: {c.texture_levels} levels need a texture of at least "
                         f"{2 ** (c.texture_levels - 1)} texels a side")
    slot = 4 * (2 ** c.index_bits if c.features == "vq" else c.feature_dim)  # float32 index logits / features
    texture = 4 * c.texture_channels * c.texture_height * c.texture_width * 4 // 3
    check_memory(hpx.grid_bytes(c.nside, 1, slot) + texture,
                 f"NeuBRDF nside={c.nside}, index_bits={c.index_bits}, texture {c.texture_height}x{c.texture_width}")


class NeuralTexture(nn.Module):
    """Learned feature texture T, `levels` mip levels of (c, h >> l, w >> l); bilinear lookup with
    wrapping uv, trilinear across levels by lod. forward(uv (N, 2), lod (N,) or None) -> (N, c).
    Texel (row i, column j) is centred at uv = ((j + 1/2) / w, 1 - (i + 1/2) / h), as everywhere in neumat."""

    def __init__(self, height: int, width: int, channels: int, levels: int, init_std: float = 0.1) -> None:
        super().__init__()
        self.levels = nn.ParameterList(
            nn.Parameter(torch.randn(channels, height >> l, width >> l) * init_std) for l in range(levels))

    def forward(self, uv: torch.Tensor, lod: torch.Tensor | None) -> torch.Tensor:
        if len(self.levels) == 1 or lod is None:
            return bilinear(self.levels[0], uv)
        return trilinear(list(self.levels), uv, lod)

    def num_parameters(self) -> int:
        return sum(p.numel() for p in self.levels)


def _after_load(module: "NeuBRDF", keys) -> None:
    """`load_state_dict`'s post-hook: the pruning levels follow the loaded grids (a function, not a lambda, so that
    a model pickles)."""
    module._update_pruning()


class NeuBRDF(LearnedMaterial):
    """NeuBRDF material model (see module docstring).

    Output: the MLP predicts log f and the model returns exp(.). Why: BRDF values are positive and span
    several decades (diffuse ~0.1, specular peaks ~1e3); the exponential keeps every output positive
    with a smooth gradient and lets the tiny MLP work in log space, where such data is close to
    piecewise smooth. Values below the horizon (wi_z <= 0 or wo_z <= 0) are 0.

    Runtime: `runtime()` freezes the indices, rounds the floats (codebook, MLP, texture) to fp16, switches to
    1/4 weights and caches, per pixel, the average of the 4 corner features and its product with the first
    MLP layer (an exact refactoring of the same function: a pixel lookup and one gather per direction replace
    the first layer). Its `state_dict` is the shipped form: b-bit indices packed (`neumat.nn.packing`), floats
    as fp16, pruning levels packed to `level_bits` bits; the training form holds 2n x 2^b float logits
    (102 MB at the defaults), which only checkpoints keep.
    """

    name = "neubrdf"
    paper = "NeuBRDF (Dou, Zheng et al. CVPR 2024)"
    source_kinds = ("brdf",)
    can_sample = False
    Config = Config

    def __init__(self, config: Config | None = None, **kwargs) -> None:
        nn.Module.__init__(self)
        cfg = resolve_config(Config, config, kwargs, 'NeuBRDF')
        _check_config(cfg)
        self.cfg = cfg
        self.spatially_varying = cfg.texture_channels > 0
        n, v, k = cfg.nside, 2 * hpx.hemisphere_size(cfg.nside), cfg.feature_dim
        if cfg.features == "vq":
            self.grid = VQFeatures(v, k, cfg.index_bits)
        elif cfg.features == "dense":
            self.grid = DenseFeatures(v, k)
        else:
            self.grid = LowBitFeatures(v, k, cfg.lowbit_bits)
        self.texture = (NeuralTexture(cfg.texture_height, cfg.texture_width, cfg.texture_channels,
                                      cfg.texture_levels) if self.spatially_varying else None)
        self.mlp = MLP(2 * k + cfg.texture_channels + DIRECTION_INPUTS[cfg.direction_inputs], cfg.hidden,
                       cfg.hidden_layers, 3, cfg.activation)
        # hierarchy level of every ring pixel for each grid (0 = unpruned; see `prune`)
        self.register_buffer("level_i", torch.zeros(12 * n * n, dtype=torch.int8))
        self.register_buffer("level_o", torch.zeros(12 * n * n, dtype=torch.int8))
        # (lookup level S+, S-, coarse training levels S+, S-) per pixel of pruned grids (`prune`), else None
        self._pruning: tuple[torch.Tensor, ...] | None = None
        self._training_steps = False  # set by `on_step` (the trainer), cleared by `train`
        self.register_load_state_dict_post_hook(_after_load)
        self.register_state_dict_post_hook(shipped_state)
        self.register_load_state_dict_pre_hook(unpack_levels)
        self.register_load_state_dict_pre_hook(regridded_state)
        self.register_load_state_dict_pre_hook(quantized_state)
        self.register_buffer("vertex_dirs", hpx.vertex2vec(n, torch.arange(hpx.nvertices(n)), torch.float32),
                             persistent=False)
        # runtime caches (see `runtime`): per-pixel mean corner features (uniform weights) or corner vertex ids
        # (inverse-distance weights), and first-layer pre-activations
        self._pixel_features: tuple[torch.Tensor, torch.Tensor] | None = None
        self._pixel_corners: tuple[torch.Tensor, torch.Tensor] | None = None
        self._runtime_table: torch.Tensor | None = None

    @property
    def config(self) -> Config:
        return self.cfg

    # ------------------------------------------------------------------------------------- lookup

    def _lookup(self, w: torch.Tensor, south: bool) -> torch.Tensor:
        """psi(w) on S+ (wi) or S- (mirrored wo): interpolated features (N, k)."""
        return self._lookup_both(((w, south),))[0]

    def _lookup_both(self, dirs) -> list[torch.Tensor]:
        """psi of each (w, south) of `dirs`, (N, k) each, with one feature-grid call for all corners (a VQ
        grid then runs its straight-through step once, on the unique slots of all lookups together)."""
        n = self.cfg.nside
        if self._pixel_features is not None:
            return [self._pixel_features[int(south)][hpx.vec2pix_unchecked(n, hpx.hemisphere_direction(w, south))]
                    for w, south in dirs]
        corners = [self._corners(w, south) for w, south in dirs]
        feats = self.grid(torch.cat([slots for _, slots, _ in corners])) if len(corners) > 1 else \
            self.grid(corners[0][1])  # (sum N, 4, k)
        out = []
        for (d, slots, vid), f in zip(corners, feats.split([slots.shape[0] for _, slots, _ in corners])):
            if self.cfg.interpolation == "uniform":
                out.append(f.mean(1))
            else:
                out.append((self._idw_weights(d, vid).unsqueeze(-1) * f).sum(1))
        return out

    def _corners(self, w: torch.Tensor, south: bool) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(the direction looked up (N, 3), grid slots (N, 4), vertex ids (N, 4)) of the corners psi reads for
        w (N, 3) on S+ or, mirrored, on S-: the corners of its pixel's lookup level (during a fit, a pruned grid's
        training levels, `_training_levels`), from the runtime's per-pixel table when it has one."""
        n = self.cfg.nside
        d = hpx.hemisphere_direction(w, south)
        pix = hpx.vec2pix_unchecked(n, d)
        if self._pixel_corners is not None:
            vid = self._pixel_corners[int(south)][pix]
            return d, (vid + hpx.south_grid_offset(n) if south else vid), vid
        if self._pruning is None:
            level = 0
        else:
            level = self._pruning[int(south)][pix]
            if self._training_steps and self.training and torch.is_grad_enabled():
                level = self._training_levels(pix, level, self._pruning[2 + int(south)])
        slots, vid = hpx.pixel_corner_slots(n, pix, south, level)
        return d, slots, vid

    def _idw_weights(self, d: torch.Tensor, vid: torch.Tensor) -> torch.Tensor:
        """Normalised inverse-distance weights (N, 4) of directions d (N, 3) to their corner vertices vid (N, 4)."""
        return hpx.idw_weights(d, self.vertex_dirs[vid].to(d.dtype))

    def _training_levels(self, pix: torch.Tensor, level: torch.Tensor, coarse: torch.Tensor) -> torch.Tensor:
        """Lookup levels (N,) while training a pruned grid: a direction in a supervised pixel whose ancestors
        are read by pruned pixels (bit masks `coarse`, see `hpx.shared_ancestor_levels`) is looked up, with
        probability `Config.pruned_ancestor_fraction`, at one of those ancestor levels (uniformly chosen), so that the
        ancestors' corners, which the pruned pixels read, learn the reflectance inside the ancestor.
        Active during a fit only (see `on_step`)."""
        mask = torch.where(level == 0, coarse[pix], 0)
        count = torch.zeros_like(mask)
        for l in range(1, self.cfg.nside.bit_length()):
            count += (mask >> l) & 1
        u = torch.rand(pix.shape, device=pix.device)
        pick = (u * (count / self.cfg.pruned_ancestor_fraction)).long()  # u < fraction -> pick < count: a coarse level
        seen = torch.zeros_like(mask)
        for l in range(1, self.cfg.nside.bit_length()):
            bit = (mask >> l) & 1
            level = torch.where((bit == 1) & (seen == pick), l, level)
            seen += bit
        return level

    def features(self, q: Query) -> torch.Tensor:
        """MLP input (N, 2 k + c (+ 6)): [psi(wi; S+), psi(mirrored wo; S-)(, T(uv))(, h, d)]."""
        wi = q.wi.to(self.vertex_dirs.dtype)
        wo = q.wo.to(self.vertex_dirs.dtype)
        parts = self._lookup_both(((wi, False), (wo, True)))
        if self.texture is not None:
            q.require("uv", who="NeuBRDF with a neural texture")
            lod = None if q.lod is None else q.lod.to(wi.dtype)
            parts.append(self.texture(q.uv.to(wi.dtype), lod))
        if self.cfg.direction_inputs != "none":
            parts.append(direction_inputs(self.cfg.direction_inputs, wi, wo))
        return torch.cat(parts, -1)

    def eval(self, q: Query) -> torch.Tensor:
        """BRDF value (N, 3), linear RGB, cosine excluded; 0 below the horizon."""
        q.require("wo", who="NeuBRDF.eval")
        if self._runtime_table is not None and self.texture is None and not torch.is_grad_enabled():
            fast = self._kernel_eval(q.wi, q.wo)
            if fast is not None:
                return fast
            return inference_call(self._masked_runtime_eval, q.wi, q.wo)
        f = torch.exp(self.mlp(self.features(q)))
        return zero_below_horizon(f, q.wi, q.wo).to(q.dtype)

    def _kernel_eval(self, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor | None:
        """The runtime form's `eval` as one fused C call (`neumat.nn.cpu_kernels`; the same values as
        `_masked_runtime_eval` within float32 rounding), or None where the kernel does not apply: inverse-distance
        corner weights, other dtypes, no compiler."""
        table = self._runtime_table
        if self.cfg.interpolation != "uniform" or not cpu_kernels.usable(wi, wo, table):
            return None
        k = cpu_kernels.prepared(self, self._kernel_bundle)
        if k is None:
            return None
        return cpu_kernels.neubrdf_eval(k.mlp, wi, wo, self.cfg.nside, table, k.first, k.columns,
                                        self.cfg.direction_inputs == "hd_warp")

    def _kernel_bundle(self) -> SimpleNamespace | None:
        """What `_kernel_eval` reads besides the table: the activation after the first layer (`first`), the layers
        after it packed (`mlp`), the direction inputs' first-layer columns (`columns`, (hidden, 6) or None); None
        where the kernels lack the activations."""
        net = self.mlp.net
        first = cpu_kernels.activation_code(net[1]) if len(net) >= 3 else None
        mlp = None if first is None else cpu_kernels.PackedMLP.pack(list(net)[2:])
        if mlp is None:
            return None
        extra = DIRECTION_INPUTS[self.cfg.direction_inputs]
        return SimpleNamespace(first=first, mlp=mlp, columns=net[0].weight[:, -extra:].detach() if extra else None)

    def _masked_runtime_eval(self, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
        """`eval` of the runtime form (`_runtime_eval`, 0 below the horizon), without the dtype conversions
        where there are none to make (a batch of one costs about as many microseconds as tensor operations)."""
        dtype = self.vertex_dirs.dtype
        out_dtype = wi.dtype
        f = self._runtime_eval(wi, wo) if dtype == out_dtype else self._runtime_eval(wi.to(dtype), wo.to(dtype))
        f = zero_below_horizon(f, wi, wo)
        return f if dtype == out_dtype else f.to(out_dtype)

    def _runtime_eval(self, wi: torch.Tensor, wo: torch.Tensor, chunk: int = 2 ** 13) -> torch.Tensor:
        """exp(MLP) from the runtime table, (N, 3), on chunks that stay in cache. Uniform weights: one pixel
        lookup for wi and wo together, then the first layer as the sum of two table rows (the pre-activations
        of the wi pixel and of the wo pixel). Inverse-distance weights: the 4 corner slots of each pixel and
        their weights, then the first layer as the weighted sum of those 8 slots' rows plus the bias. Then the
        rest of the MLP; with `Config.direction_inputs`, their first-layer columns times the inputs are added
        before the activation. Directions below the horizon give finite values that the caller masks."""
        n, m = self.cfg.nside, wi.shape[0]
        chunk = rows_per_slice(chunk, wi.device)
        # the direction inputs' first-layer columns (the last ones), (extra, hidden)
        kind = self.cfg.direction_inputs
        extra = DIRECTION_INPUTS[kind]
        hd_weight = self.mlp.net[0].weight[:, -extra:].t() if extra else None
        out = None if 0 < m <= chunk else torch.empty(m, 3, dtype=self._runtime_table.dtype, device=wi.device)
        for s in range(0, m, chunk):
            c = min(chunk, m - s)
            if self.cfg.interpolation == "idw":
                corners = [self._corners(w[s:s + c], south) for w, south in ((wi, False), (wo, True))]
                rows = torch.cat([slots for _, slots, _ in corners], -1)
                weights = torch.cat([self._idw_weights(d, vid) for d, _, vid in corners],
                                    -1).to(self._runtime_table.dtype)
                h = nn.functional.embedding_bag(rows, self._runtime_table, per_sample_weights=weights,
                                                mode="sum").add_(self.mlp.net[0].bias)
            else:
                pair = (wi, wo) if c == m else (wi[s:s + c], wo[s:s + c])
                x, y, z = torch.cat(pair, -1).view(2 * c, 3).t().contiguous()  # coordinate rows of wi0, wo0, wi1 ..
                pix = hpx.vec2pix_xyz(n, x, y, z).view(c, 2)
                pix.add_(cached_tensor((0, 12 * n * n), pix.dtype, pix.device))  # wo: the S- half
                h = nn.functional.embedding_bag(pix, self._runtime_table, mode="sum")
            if hd_weight is not None:
                h.addmm_(direction_inputs(kind, wi[s:s + c], wo[s:s + c]).to(h.dtype), hd_weight)
            h = self.mlp.run_layers(h, 1)
            if out is None:  # one chunk
                return torch.exp(h)
            torch.exp(h, out=out[s:s + c])
        return out

    def forward(self, q: Query) -> torch.Tensor:
        return self.eval(q)

    @torch.no_grad()
    def init_from_targets(self, target: torch.Tensor) -> None:
        """Start at the data's scale (trainer hook, before the first step): last MLP layer weights 0 and
        biases log(median) per channel of `target` (N, 3) (clamped to >= 1e-4): the model first predicts the
        median, constant. Why: see `neumat.methods.neubrdf.train`."""
        if target.ndim != 2 or target.shape[1] != 3:
            raise InputError(f"NeuBRDF.init_from_targets: expected targets (N, 3), got {tuple(target.shape)}")
        self.mlp.start_constant(log_median(target))
        self._drop_runtime()

    def optimizer(self, lr: float, betas: tuple[float, float] = (0.9, 0.999), eps: float = 1e-8) -> RowAdam:
        """The optimiser to train this model with (the trainer's hook): Adam on every trainable parameter,
        with the VQ logits switched to sparse row gradients and updated lazily, only on the vertices of
        each batch (a dense Adam step would touch all 2n x 2^b logits, 25.6 M at the defaults), at
        `Config.index_lr_scale` times the learning rate."""
        return grid_optimizer(self, self.grid, lr, betas, eps, self.cfg.index_lr_scale)

    # ------------------------------------------------------------------------ pruning and runtime

    def prune(self, wi: torch.Tensor, wo: torch.Tensor) -> None:
        """Multi-resolution sparse grids from the supervised directions wi, wo (N, 3) (paper Sec. 3.2.1):
        a pixel holding no training direction uses the corners of its nearest ancestor that holds one. Call
        before training on sparse measurements: training then also looks directions up at those ancestor
        levels (`Config.pruned_ancestor_fraction` of the lookups, see `_training_levels`), so that the corners the
        pruned pixels read are trained on the reflectance inside the ancestor, not left at their initial values."""
        n = self.cfg.nside
        for south, w, name in ((False, wi, "wi"), (True, wo, "wo")):
            check_directions(w, f"NeuBRDF.prune {name}")
            sup = hpx.supervised_pixels(n, hpx.hemisphere_direction(w, south))
            getattr(self, "level_o" if south else "level_i").copy_(hpx.pruned_levels(n, sup).to(torch.int8))
        self._update_pruning()
        self._drop_runtime()

    def _update_pruning(self) -> None:
        """Lookup levels of the pruned grids: `level_i` / `level_o` capped where the ancestor's corners
        would leave the hemisphere grid (`hpx.grid_level_cap`), and the ancestor levels to train."""
        for name in ("level_i", "level_o"):
            hpx.check_levels(getattr(self, name), self.cfg.nside, f"NeuBRDF.{name}")
        if bool((self.level_i == 0).all()) and bool((self.level_o == 0).all()):
            self._pruning = None
            return
        n = self.cfg.nside
        levels = [capped_levels(n, level, south) for south, level in ((False, self.level_i), (True, self.level_o))]
        self._pruning = (*levels, *(hpx.shared_ancestor_levels(n, level) for level in levels))

    def used_slots(self) -> torch.Tensor:
        """Mask (2 n,) of grid slots referenced by some pixel of the (pruned) grids."""
        return used_slot_mask(self.cfg.nside, None if self._pruning is None else self._pruning[:2],
                              self.level_i.device)

    @property
    def is_runtime(self) -> bool:
        """Whether `runtime()` is in effect (model files record it and re-enter runtime mode on load)."""
        return self._runtime_table is not None

    def freeze(self) -> None:
        """Freeze the vertex features to integers (indices or low-bit codes) for export."""
        self.grid.freeze()
        self._drop_runtime()

    @torch.no_grad()
    def quantize_from_dense(self, index_bits: int | None = None, iterations: int = 25, margin: float = 1.0,
                            seed: int = 0, candidates: int = 0, weights: torch.Tensor | None = None) -> "NeuBRDF":
        """End of a dense warm-up: replace dense per-slot features by a VQ grid that starts at them.

        The codebook (2^b, k) is the k-means clustering (Lloyd, `iterations` rounds from a k-means++ start
        drawn with `seed`) of the features of the slots that some pixel reads (`used_slots`), each
        slot's index logits start at 0.01 N(0, 1) plus `margin` on its nearest codeword (so the argmax is the
        nearest codeword), and `Config.features` becomes "vq" (`index_bits` defaults to `Config.index_bits`).
        `candidates` K in [1, 2^b]: each slot keeps the logits of its K nearest codewords only
        (`VQFeatures.restrict`: steps cost O(K) per slot instead of O(2^b)); 0 keeps all 2^b.
        `weights` (2 n, k), >= 0: weighted k-means, the distance of slot s to codeword c being
        sum_j weights[s, j] (x_sj - c_j)^2 and each codeword the weighted mean of its slots per channel (the
        nearest codeword and the candidates by the same distance); e.g. how much the loss depends on each slot's
        channels (`neumat.methods.neubrdf.feature_sensitivity`), so the codewords go where errors cost most. None: plain
        k-means. Returns self. Build the optimiser again afterwards (`optimizer`): the parameters changed."""
        return quantize_dense_grid(self, "NeuBRDF.quantize_from_dense", index_bits, iterations=iterations,
                                   margin=margin, seed=seed, candidates=candidates, weights=weights)

    def _use_vq_grid(self, vq: VQFeatures) -> None:
        """Install the VQ grid `vq` (this grid's rows) in place of the current one; `Config.features` becomes
        "vq" with vq's index bits."""
        self.grid = vq
        self.cfg = replace(self.cfg, features="vq", index_bits=vq.bits)
        self._drop_runtime()

    def grid_rows(self, nside: int) -> int:
        """Slots of a feature grid at `nside` (2 n: S+ and S-)."""
        return 2 * hpx.hemisphere_size(nside)

    @torch.no_grad()
    def regrid(self, nside: int) -> "NeuBRDF":
        """Coarse to fine (or fine to coarse): replace the feature grid by a dense grid at `nside` whose slot
        features are this model's interpolated features psi (training form) at the slots' directions, the MLP
        kept, so the model's function carries over up to re-sampling (`Config.nside` becomes `nside`). Slots
        past the equator take psi at the equator. Why: at N_side 64 each of the 49,922 slots sees about 1.3 of
        the 8 x 8192 corner reads of a step, and a fit started there spends its first thousands of steps
        moving random features; trained at N_side 16 first (3,266 slots), the grid starts near the answer.
        Not for pruned or low-bit grids. Returns self; build the optimiser again."""
        nside = hpx.check_nside(nside, "NeuBRDF.regrid nside", power_of_two=True)
        if self.pruned:
            raise InputError("NeuBRDF.regrid: a pruned grid cannot be re-sampled (prune after regridding)")
        if isinstance(self.grid, LowBitFeatures):
            raise InputError("NeuBRDF.regrid: expected a model with features 'dense' or 'vq'")
        new_cfg = replace(self.cfg, nside=nside, features="dense")
        _check_config(new_cfg)
        dirs, h = hpx.grid_slot_directions(nside).to(self.vertex_dirs), hpx.hemisphere_size(nside)
        feats = torch.cat([self._lookup(dirs[:h], False), self._lookup(dirs[h:], True)])
        self._set_dense_grid(new_cfg, feats)
        return self

    @torch.no_grad()
    def init_direction_features(self, scale: float = 1.0) -> "NeuBRDF":
        """Start the first 3 feature channels of every slot at `scale` times the slot's vertex direction on the
        sphere (S+ slots above the equator, S- slots below it); the other channels keep their random start.
        psi(wi; S+)[:3] then begins near scale wi and psi(wo mirrored; S-)[:3] near scale (wo_x, wo_y, -wo_z)
        (inverse-distance interpolation: within half a pixel), and at the mirror direction the two cancel (the
        mirrored wo is -wi, whose pixel and weights are wi's, antipodal), so the first MLP layer sees about
        scale (wi - reflect(wo)) from the first step and can place a specular peak finer than a pixel. Why: from
        random features no fit of MERL-like chrome found its 0.5-degree peak (`benchmarks/studies/neubrdf/results/
        neubrdf_direction_init.md`). Dense features only; returns self."""
        if not isinstance(self.grid, DenseFeatures):
            raise InputError("NeuBRDF.init_direction_features: needs a model with features='dense' "
                             f"(got {self.cfg.features!r})")
        if self.cfg.feature_dim < 3:
            raise InputError(f"NeuBRDF.init_direction_features: needs feature_dim >= 3, got {self.cfg.feature_dim}")
        dirs = hpx.vertex2vec(self.cfg.nside, hpx.grid_vertex_ids(self.cfg.nside), torch.float64)
        self.grid.features[:, :3] = (scale * dirs).to(self.grid.features)
        self._drop_runtime()
        return self

    def _set_dense_grid(self, cfg: Config, feats: torch.Tensor) -> None:
        """Install a dense grid at cfg.nside holding `feats` (2 n, k), and the buffers of that size."""
        device = self.level_i.device
        n = cfg.nside
        self.grid = DenseFeatures.holding(feats.to(device), next(self.mlp.parameters()).requires_grad)
        self.cfg = cfg
        self.level_i = torch.zeros(12 * n * n, dtype=torch.int8, device=device)
        self.level_o = torch.zeros(12 * n * n, dtype=torch.int8, device=device)
        self.vertex_dirs = hpx.vertex2vec(n, torch.arange(hpx.nvertices(n)), torch.float32).to(self.vertex_dirs)
        self._pruning = None
        self._drop_runtime()

    def train(self, mode: bool = True) -> "NeuBRDF":
        """torch train / inference switch; training drops the runtime cache (it would go stale)."""
        if mode:
            self._drop_runtime()
        self._training_steps = False
        return super().train(mode)

    def on_step(self, step: int, total_steps: int) -> None:
        """Trainer hook, called before every training step: from now until the next `train()` call,
        lookups with gradient in training mode use the coarse training levels of pruned grids (see
        `_training_levels`); evaluation outside a fit stays deterministic."""
        self._training_steps = True

    def _apply(self, fn, recurse: bool = True):
        """`.to()`, `.cuda()`, `.half()` ... also move the pruning levels and the runtime caches (plain
        attributes, tuples of tensors), so a model moved after `prune` or `runtime()` keeps working."""
        super()._apply(fn, recurse)
        for name in ("_pruning", "_pixel_features", "_pixel_corners", "_runtime_table"):
            value = getattr(self, name)
            if isinstance(value, torch.Tensor):
                setattr(self, name, fn(value))
            elif value is not None:
                setattr(self, name, tuple(fn(t) for t in value))
        return self

    def _drop_runtime(self) -> None:
        self._pixel_features = None
        self._pixel_corners = None
        self._runtime_table = None

    @torch.no_grad()
    def runtime(self) -> "NeuBRDF":
        """Switch to the paper's runtime mode: frozen indices, floats rounded to fp16 (what the model file
        stores, see `shipped_state`: a saved and loaded runtime model evaluates bit for bit like this one),
        the corner weights of `Config.runtime_interpolation` (1/4 by default), caches.

        Uniform weights cache, for every ring pixel p of each grid: the mean F(p) of its 4 (ancestor) corner
        features, and the first-layer pre-activations W_i F_i(p) + b and W_o F_o(p) (W = [W_i, W_o] the first
        MLP layer), stacked in one table (2 x 12 N_side^2, hidden), the latter indexed by the pixel of the
        unmirrored wo. Evaluation is then two pixel lookups, two gathers, an add and the rest of the MLP: the
        same function as `interpolation="uniform"`. Inverse-distance weights cache W_i f(s) for every slot s of
        S+ and W_o f(s) for every slot of S- (2 n, hidden) and every pixel's 4 (ancestor) corner vertex ids:
        evaluation is a pixel lookup per direction, the weighted sum of the 8 corner rows, the bias and the
        rest of the MLP, the same function as `interpolation="idw"`."""
        self.freeze()
        for p in self.parameters():
            p.copy_(p.half())
        self.cfg = replace(self.cfg, interpolation=self.cfg.runtime_interpolation)
        n, k = self.cfg.nside, self.cfg.feature_dim
        first = self.mlp.net[0]
        pix = torch.arange(12 * n * n, device=self.level_i.device)
        if self.cfg.interpolation == "idw":
            feats = self.grid(torch.arange(self.grid.num_vertices, device=self.level_i.device))
            h = hpx.hemisphere_size(n)
            self._runtime_table = torch.cat([feats[:h] @ first.weight[:, :k].t(),
                                             feats[h:] @ first.weight[:, k:2 * k].t()])
            self._pixel_corners = tuple(
                hpx.pixel_corner_slots(n, pix, south, 0 if self._pruning is None else self._pruning[int(south)])[1]
                for south in (False, True))
            return self.train(False)
        self._pixel_features = self._pixel_mean_features()
        # on huge pages: a 24 MB table read at random rows (the kernel 1.00-1.07x, NOTES.md)
        self._runtime_table = cpu_kernels.on_huge_pages(self._pixel_first_layer(self._pixel_features))
        return self.train(False)

    @torch.no_grad()
    def _pixel_mean_features(self) -> tuple[torch.Tensor, torch.Tensor]:
        """Per ring pixel of S+ and of S- (12 N_side^2, k) each: the mean of its 4 (ancestor) corner features,
        what uniform weights interpolate (`runtime`); 0 for pixels outside the hemisphere (never looked up)."""
        n = self.cfg.nside
        pix = torch.arange(12 * n * n, device=self.level_i.device)
        tables = []
        for south in (False, True):
            vid = hpx.ancestor_corner_vertices(n, pix, 0 if self._pruning is None else self._pruning[int(south)])
            ok = (vid >= hpx.nvertices(n) - hpx.hemisphere_size(n)) if south else (vid < hpx.hemisphere_size(n))
            slots = (vid + hpx.south_grid_offset(n) if south else vid).clamp(0, 2 * hpx.hemisphere_size(n) - 1)
            tables.append(torch.where(ok.all(-1, keepdim=True), self.grid(slots).mean(1), 0.0))
        return tables[0], tables[1]

    @torch.no_grad()
    def _pixel_first_layer(self, tables: tuple[torch.Tensor, torch.Tensor]) -> torch.Tensor:
        """The uniform-weight runtime table (2 x 12 N_side^2, hidden) of per-pixel mean features `tables`
        (`_pixel_mean_features`): rows W_i F_i(p) + b for the wi pixel p, then rows W_o F_o(mirror(p)) for the
        pixel p of the unmirrored wo (`runtime`)."""
        n, k = self.cfg.nside, self.cfg.feature_dim
        first = self.mlp.net[0]
        w_i, w_o = first.weight[:, :k], first.weight[:, k:2 * k]
        pre_o = tables[1][hpx.mirror_pixels(n).to(tables[1].device)] @ w_o.t()
        return torch.cat([torch.addmm(first.bias, tables[0], w_i.t()), pre_o])

    @torch.no_grad()
    def pixel_first_layer_table(self) -> torch.Tensor:
        """The first-layer table of uniform corner weights (2 x 12 N_side^2, hidden), `_pixel_first_layer`: the
        runtime's own table in runtime form with uniform weights, else computed from the current features and
        first layer (what `eval` with `interpolation="uniform"` computes, refactored; the GLSL export's
        `nbrdf_first`)."""
        if self.is_runtime and self.cfg.interpolation == "uniform":
            return self._runtime_table
        return self._pixel_first_layer(self._pixel_mean_features())

    # ------------------------------------------------------------------------------------ storage

    def grid_size_bytes(self, precision: str = "fp16") -> int:
        """Bytes of the spherical grid: b-bit indices of the 2 n slots plus the 2^b x k codebook
        (vq; the paper's formula 2 n b + p k 2^b bits), or the dense / low-bit features."""
        return storage_bytes(self.grid.storage_bits(float_bits(precision)))

    @property
    def level_bits(self) -> int:
        """Bits of a stored pruning level (levels run from 0 to log2 N_side)."""
        return max(1, (self.cfg.nside.bit_length() - 1).bit_length())

    @property
    def pruned(self) -> bool:
        """Whether `prune` made some pixel look up an ancestor level."""
        return self._pruning is not None

    def size_bytes(self, precision: str = "fp16") -> int:
        """Stored size: grid (see `grid_size_bytes`) + MLP weights and biases + neural texture, floats at
        `precision`, + the pruning levels of a pruned grid (`level_bits` per pixel of both grids; an
        unpruned grid needs none, as in the paper's count). A pruned VQ grid stores the indices of the
        slots some pixel reads only (`used_slots`; the paper's 2 n b with n the used slots): the others
        follow from the levels. Levels that `prune` made are stored as the 1-bit mask of supervised pixels
        they follow from (`levels_from_mask`), others at `level_bits` each. The runtime model file holds
        this plus its header and, unpruned, the all-zero levels as such a mask (2 x 12 N_side^2 bits, 12 KB
        at N_side 64)."""
        fb = float_bits(precision)
        floats = self.mlp.num_parameters() + (self.texture.num_parameters() if self.texture is not None else 0)
        per_pixel = 1 if all(levels_from_mask(self.cfg.nside, lv) for lv in (self.level_i, self.level_o)) \
            else self.level_bits
        levels = 2 * 12 * self.cfg.nside ** 2 * per_pixel if self.pruned else 0
        grid = self.grid.storage_bits(fb)
        if self.pruned and isinstance(self.grid, VQFeatures):  # only the slots some pixel reads are stored
            grid -= int((~self.used_slots()).sum()) * self.grid.bits
        return storage_bytes(grid + floats * fb + levels)

    def flops(self) -> int:
        """MLP floating-point operations per evaluation (feature lookups not counted)."""
        return self.mlp.flops()


def shipped_state(module, state_dict: dict, prefix: str, local_metadata) -> None:
    """State-dict hook of NeuBRDF-like models (NeuBRDF, SharedNeuBRDF): in runtime mode the state is the
    shipped form, floats as fp16 (exact: `runtime` rounded them) and the pruning levels `level_i` /
    `level_o` packed to `module.level_bits` bits as "packed_level_i" / "packed_level_o", or for a NeuBRDF
    whose levels follow from their supervised pixels (`levels_from_mask`: all that `prune` makes) as that
    1-bit mask, "supervised_level_i" / "supervised_level_o" (the grid packs its own indices; a pruned VQ
    grid stores those of the used slots only, "packed_used_index"); training and frozen models keep their
    float32 state."""
    if not module.is_runtime:
        return
    for key, value in state_dict.items():
        if key.startswith(prefix) and value.is_floating_point():
            state_dict[key] = value.half()
    for name in ("level_i", "level_o"):
        level = state_dict.pop(prefix + name)
        if isinstance(module, NeuBRDF) and levels_from_mask(module.cfg.nside, level):
            state_dict[prefix + "supervised_" + name] = pack_bits((level == 0).flatten().long(), 1)
        else:
            state_dict[prefix + "packed_" + name] = pack_bits(level.flatten().long(), module.level_bits)
    key = prefix + "grid.packed_index"
    if isinstance(module, NeuBRDF) and module.pruned and key in state_dict:  # pruned VQ grid: used slots only
        grid = module.grid
        used = module.used_slots()
        index = unpack_bits(state_dict.pop(key), grid.bits, grid.num_vertices, key)
        state_dict[prefix + "packed_used_index"] = pack_bits(index[used.to(index.device)], grid.bits)


@torch.no_grad()
def quantize_dense_grid(model, who: str, index_bits: int | None, **kmeans):
    """`quantize_from_dense` of NeuBRDF-like models (NeuBRDF, SharedNeuBRDF: `grid`, `cfg.index_bits`, `used_slots`,
    `_use_vq_grid`): the dense grid replaced by `neumat.nn.codebook_kmeans.vq_from_dense` of its used slots (keywords
    `kmeans`: iterations, margin, seed, candidates, weights); `who` names the caller in errors. Returns model."""
    if not isinstance(model.grid, DenseFeatures):
        raise InputError(f"{who}: expected a model with features='dense'")
    bits = model.cfg.index_bits if index_bits is None else check_int(index_bits, "index_bits")
    model._use_vq_grid(vq_from_dense(model.grid.features, model.used_slots(), bits, who=who, **kmeans))
    return model


def regridded_state(module, state_dict: dict, prefix: str, local_metadata, strict, missing_keys,
                    unexpected_keys, error_msgs) -> None:
    """Load-state-dict pre-hook of NeuBRDF-like models (NeuBRDF, SharedNeuBRDF: `grid_rows`, `_set_dense_grid`,
    `pruned`): a model given the training state of a grid at another N_side (a checkpoint written after `regrid`,
    e.g. resuming a coarse-to-fine fit) is given a dense grid of that N_side first (the state's own values then
    load; `quantized_state` makes it a VQ grid if the state is one)."""
    if module.pruned:
        return
    rows = next((state_dict[prefix + k].shape[0] for k in ("grid.features", "grid.logits")
                 if prefix + k in state_dict), None)
    if rows is None or rows == module.grid.num_vertices:
        return
    nside = next((n for n in (2 ** i for i in range(14)) if module.grid_rows(n) == rows), None)
    if nside is None:
        return  # not a grid size of this model: the load reports the mismatch
    like = next(module.mlp.parameters())
    feats = torch.zeros(rows, module.cfg.feature_dim, device=like.device, dtype=like.dtype)
    module._set_dense_grid(replace(module.cfg, nside=nside, features="dense"), feats)


def quantized_state(module, state_dict: dict, prefix: str, local_metadata, strict, missing_keys,
                    unexpected_keys, error_msgs) -> None:
    """Load-state-dict pre-hook of NeuBRDF-like models (`_use_vq_grid`): a dense model given the training state
    of a VQ grid (a checkpoint written after `quantize_from_dense`, e.g. resuming a fit with a dense warm-up past
    the switch) becomes a VQ model of the state's index bits first, as `quantize_from_dense` made it, so that the
    state loads."""
    if not isinstance(module.grid, DenseFeatures) or prefix + "grid.logits" not in state_dict:
        return
    bits = int(state_dict[prefix + "grid.codebook"].shape[0]).bit_length() - 1
    dense = module.grid.features
    vq = VQFeatures(module.grid.num_vertices, module.grid.dim, bits).to(dense.device, dense.dtype)
    vq.requires_grad_(dense.requires_grad)
    module._use_vq_grid(vq)


def unpack_levels(module, state_dict: dict, prefix: str, local_metadata, strict, missing_keys, unexpected_keys,
                  error_msgs) -> None:
    """Load-state-dict pre-hook inverting `shipped_state`: packed pruning levels back to int8 pixel levels."""
    for name in ("level_i", "level_o"):
        key = prefix + "packed_" + name
        shape = getattr(module, name).shape
        if key in state_dict:
            state_dict[prefix + name] = unpack_bits(state_dict.pop(key), module.level_bits, shape.numel(),
                                                    key).to(torch.int8).view(shape)
        key = prefix + "supervised_" + name
        if key in state_dict:
            mask = unpack_bits(state_dict.pop(key), 1, shape.numel(), key).bool()
            state_dict[prefix + name] = hpx.pruned_levels(module.cfg.nside, mask).to(torch.int8).view(shape)
    key = prefix + "packed_used_index"
    if key in state_dict and isinstance(module, NeuBRDF) and isinstance(module.grid, VQFeatures):  # pruned grid
        n, grid = module.cfg.nside, module.grid
        levels = [capped_levels(n, state_dict[prefix + name].long(), south)
                  for south, name in ((False, "level_i"), (True, "level_o"))]
        used = used_slot_mask(n, levels, levels[0].device)
        index = torch.zeros(grid.num_vertices, dtype=torch.long)
        index[used.cpu()] = unpack_bits(state_dict.pop(key), grid.bits, int(used.sum()), key)
        state_dict[prefix + "grid.packed_index"] = pack_bits(index, grid.bits)


def levels_from_mask(nside: int, level: torch.Tensor) -> bool:
    """Whether pruning levels (12 nside^2,) are those of `hpx.pruned_levels` of their supervised pixels
    (level 0), so that storing that 1-bit mask restores them (true of every grid `prune` made and of an
    unpruned one; nside a power of two)."""
    if nside & (nside - 1) or level.ndim != 1:
        return False
    return torch.equal(hpx.pruned_levels(nside, level == 0), level.long())


def capped_levels(nside: int, level: torch.Tensor, south: bool) -> torch.Tensor:
    """Lookup levels (12 nside^2,) int64 of a pruned grid: `level` capped where the ancestor's corners would
    leave the hemisphere grid (`hpx.grid_level_cap`)."""
    return torch.minimum(level.long(), hpx.grid_level_cap(nside, south).clamp(min=0).to(level.device))


def used_slot_mask(nside: int, levels, device=None) -> torch.Tensor:
    """Mask (2 n,) of the grid slots some hemisphere pixel reads, for lookup levels (S+, S-) from
    `capped_levels` (None: unpruned)."""
    n = nside
    mask = torch.zeros(2 * hpx.hemisphere_size(n), dtype=torch.bool, device=device)
    pix = torch.arange(12 * n * n, device=mask.device)
    z = hpx.pix2vec(n, pix)[:, 2].to(mask.device)
    for south, keep in ((False, z >= -1e-12), (True, z <= 1e-12)):
        p = pix[keep]
        vid = hpx.ancestor_corner_vertices(n, p, 0 if levels is None else levels[int(south)][p])
        mask[vid + hpx.south_grid_offset(n) if south else vid] = True
    return mask
