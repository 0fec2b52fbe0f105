"""NeuBRDF (Dou, Zheng et al., CVPR 2024): HEALPix spherical index grids for wi and wo, a codebook of
neural reflectance primitives, a tiny MLP; optional neural-texture plug-in for spatially varying
materials and BTFs.

f(wi, wo[, uv]) = exp(m([psi(wi; S+), psi(wo_mirrored; S-)[, phi(uv; T)]]))      (paper Eq. 1, 3, 4)

psi interpolates the features of the 4 corner vertices of the HEALPix pixel that holds the direction,
with normalised inverse great-circle-distance weights (training) or 1/4 each (runtime). `wi` is looked
up on the north grid S+, `wo` mirrored to (pi - theta, phi) on the south grid S-; see `neumat.nn.healpix`.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import torch
from torch import nn

from neumat.core.checks import check_directions
from neumat.core.config import config_from_dict
from neumat.core.errors import InputError
from neumat.core.material import Material, upper_hemisphere
from neumat.core.query import Query
from neumat.nn import healpix as hpx
from neumat.nn.codebook import DenseFeatures, LowBitFeatures, VQFeatures, float_bits, storage_bytes
from neumat.models.registry import MODELS
from neumat.nn.mlp import MLP


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
    activation: str = "relu"
    """Hidden activation of the MLP."""
    features: str = "vq"
    """Vertex feature storage: "vq" (codebook indices, the paper), "dense" (floats per vertex) or
    "lowbit" (per-vertex features quantised to `lowbit_bits` bits); the last two are the Table 4 ablations."""
    lowbit_bits: int = 4
    """Bits per feature value in "lowbit" mode."""
    interpolation: str = "idw"
    """Corner weights: "idw" (normalised inverse great-circle distance, training) or "uniform" (1/4, runtime)."""
    texture_height: int = 0
    """h of the neural texture T (h x w x c) for spatially varying materials; 0 without texture."""
    texture_width: int = 0
    """w of the neural texture T."""
    texture_channels: int = 0
    """c of the neural texture T; 0 disables the texture plug-in."""
    texture_levels: int = 1
    """Mip levels of T (level l is h / 2^l x w / 2^l, each learned); Query.lod blends them trilinearly."""


def _check_config(c: Config) -> None:
    def pos_int(name: str, lo: int = 1) -> None:
        v = getattr(c, name)
        if isinstance(v, bool) or not isinstance(v, int) or v < lo:
            raise InputError(f"NeuBRDF.{name}: expected an integer >= {lo}, got {v!r}")

    for name in ("nside", "feature_dim", "index_bits", "hidden", "lowbit_bits", "texture_levels"):
        pos_int(name)
    for name in ("hidden_layers", "texture_height", "texture_width", "texture_channels"):
        pos_int(name, 0)
    hpx.check_nside(c.nside, "NeuBRDF.nside", power_of_two=True)
    if c.index_bits > 16:
        raise InputError(f"NeuBRDF.index_bits: expected 1 .. 16, got {c.index_bits}")
    if c.lowbit_bits > 8:
        raise InputError(f"NeuBRDF.lowbit_bits: expected 1 .. 8, got {c.lowbit_bits}")
    if c.features not in ("vq", "dense", "lowbit"):
        raise InputError(f"NeuBRDF.features: expected 'vq', 'dense' or 'lowbit', got {c.features!r}")
    if c.interpolation not in ("idw", "uniform"):
        raise InputError(f"NeuBRDF.interpolation: expected 'idw' or 'uniform', got {c.interpolation!r}")
    if c.texture_channels and (c.texture_height < 1 or c.texture_width < 1):
        raise InputError("NeuBRDF.texture_height/texture_width: expected >= 1 with texture_channels > 0")
    if c.texture_channels and min(c.texture_height, c.texture_width) >> (c.texture_levels - 1) < 1:
        raise InputError(f"NeuBRDF.texture_levels: {c.texture_levels} levels need a texture of at least "
                         f"{2 ** (c.texture_levels - 1)} texels a side")


class NeuralTexture(nn.Module):
    """Learned feature texture T, `levels` mip levels of (c, h >> l, w >> l); bilinear lookup with
    wrapping uv, trilinear across levels by lod. forward(uv (N, 2), lod (N,) or None) -> (N, c)."""

    def __init__(self, height: int, width: int, channels: int, levels: int, init_std: float = 0.1) -> None:
        super().__init__()
        self.levels = nn.ParameterList(
            nn.Parameter(torch.randn(channels, height >> l, width >> l) * init_std) for l in range(levels))

    def forward(self, uv: torch.Tensor, lod: torch.Tensor | None) -> torch.Tensor:
        if len(self.levels) == 1 or lod is None:
            return self._bilinear(self.levels[0], uv)
        lod = lod.clamp(0, len(self.levels) - 1)
        lo = lod.floor().long()
        hi = (lo + 1).clamp(max=len(self.levels) - 1)
        t = (lod - lo).unsqueeze(-1)
        out = torch.zeros(uv.shape[0], self.levels[0].shape[0], device=uv.device, dtype=uv.dtype)
        for l, tex in enumerate(self.levels):
            wl = torch.where(lo == l, 1 - t.squeeze(-1), 0.0) + torch.where(hi == l, t.squeeze(-1), 0.0)
            if bool((wl > 0).any()):
                out = out + wl.unsqueeze(-1) * self._bilinear(tex, uv)
        return out

    @staticmethod
    def _bilinear(tex: torch.Tensor, uv: torch.Tensor) -> torch.Tensor:
        c, h, w = tex.shape
        x = uv[:, 0] * w - 0.5
        y = uv[:, 1] * h - 0.5
        x0, y0 = x.floor(), y.floor()
        fx, fy = (x - x0).unsqueeze(-1), (y - y0).unsqueeze(-1)
        x0, y0 = x0.long() % w, y0.long() % h
        x1, y1 = (x0 + 1) % w, (y0 + 1) % h
        flat = tex.reshape(c, h * w).t()
        g = lambda yy, xx: flat[yy * w + xx]  # noqa: E731
        return ((1 - fy) * ((1 - fx) * g(y0, x0) + fx * g(y0, x1)) + fy * ((1 - fx) * g(y1, x0) + fx * g(y1, x1)))

    def num_parameters(self) -> int:
        return sum(p.numel() for p in self.levels)


@MODELS.register("neubrdf")
class NeuBRDF(nn.Module, Material):
    """NeuBRDF material model (see module docstring).

    Output: the MLP predicts log f and the model returns exp(.). Why: BRDF values are positive and span
    several decades (diffuse ~0.1, specular peaks ~1e3); the exponential keeps every output positive
    with a smooth gradient and lets the tiny MLP work in log space, where such data is close to
    piecewise smooth. Values below the horizon (wi_z <= 0 or wo_z <= 0) are 0.

    Runtime: `runtime()` freezes the indices, switches to 1/4 weights and caches the per-pixel average
    of the 4 corner features (an exact refactoring of the same function: lookup + one gather).
    """

    name = "neubrdf"
    can_sample = False
    Config = Config

    def __init__(self, config: Config | None = None, **kwargs) -> None:
        nn.Module.__init__(self)
        if config is not None and kwargs:
            raise InputError("NeuBRDF: pass either a Config or keyword fields, not both")
        cfg = config if config is not None else config_from_dict(Config, kwargs)
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
        self.mlp = MLP(2 * k + cfg.texture_channels, cfg.hidden, cfg.hidden_layers, 3, cfg.activation)
        # hierarchy level of every ring pixel for each grid (0 = unpruned; see `prune`)
        self.register_buffer("level_i", torch.zeros(12 * n * n, dtype=torch.int8))
        self.register_buffer("level_o", torch.zeros(12 * n * n, dtype=torch.int8))
        self.register_buffer("vertex_dirs", hpx.vertex2vec(n, torch.arange(hpx.nvertices(n)), torch.float32),
                             persistent=False)
        self._pixel_features: tuple[torch.Tensor, torch.Tensor] | None = None

    @property
    def config(self) -> Config:
        return self.cfg

    # ------------------------------------------------------------------------------------- lookup

    def _lookup(self, w: torch.Tensor, south: bool) -> torch.Tensor:
        """psi(w) on S+ (wi) or S- (mirrored wo): interpolated features (N, k)."""
        n = self.cfg.nside
        if self._pixel_features is not None:
            return self._pixel_features[int(south)][hpx.vec2pix_unchecked(n, hpx.hemisphere_direction(w, south))]
        slots, vid, d = hpx.grid_corners(n, w, south, self.level_o if south else self.level_i)
        feats = self.grid(slots)  # (N, 4, k)
        if self.cfg.interpolation == "uniform":
            return feats.mean(1)
        wts = hpx.idw_weights(d, self.vertex_dirs[vid].to(d.dtype))
        return (wts.unsqueeze(-1) * feats).sum(1)

    def features(self, q: Query) -> torch.Tensor:
        """MLP input (N, 2 k + c): [psi(wi; S+), psi(mirrored wo; S-)(, T(uv))]."""
        wi = q.wi.to(self.vertex_dirs.dtype)
        wo = q.wo.to(self.vertex_dirs.dtype)
        parts = [self._lookup(wi, False), self._lookup(wo, True)]
        if self.texture is not None:
            q.require("uv", who="NeuBRDF with a neural texture")
            lod = None if q.lod is None else q.lod.to(wi.dtype)
            parts.append(self.texture(q.uv.to(wi.dtype), lod))
        return torch.cat(parts, -1)

    def eval(self, q: Query) -> torch.Tensor:
        """BRDF value (N, 3), linear RGB, cosine excluded; 0 below the horizon."""
        q.require("wo", who="NeuBRDF.eval")
        if self._pixel_features is not None and self.texture is None and not torch.is_grad_enabled():
            f = self._runtime_eval(q.wi.to(self.vertex_dirs.dtype), q.wo.to(self.vertex_dirs.dtype))
        else:
            f = torch.exp(self.mlp(self.features(q)))
        f = torch.where(upper_hemisphere(q.wi, q.wo).unsqueeze(-1), f, torch.zeros_like(f))
        return f.to(q.dtype)

    def _runtime_eval(self, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
        """exp(MLP) of cached per-pixel features; one pixel lookup for wi and mirrored wo together."""
        n = wi.shape[0]
        d = torch.cat([hpx.hemisphere_direction(wi, False), hpx.hemisphere_direction(wo, True)])
        pix = hpx.vec2pix_unchecked(self.cfg.nside, d)
        fi, fo = self._pixel_features
        x = torch.cat([fi.index_select(0, pix[:n]), fo.index_select(0, pix[n:])], -1)
        return torch.exp(self.mlp(x))

    def forward(self, q: Query) -> torch.Tensor:
        return self.eval(q)

    # ------------------------------------------------------------------------ pruning and runtime

    def prune(self, wi: torch.Tensor, wo: torch.Tensor) -> None:
        """Multi-resolution sparse grids from the supervised directions wi, wo (N, 3) (paper Sec. 3.2.1):
        a pixel holding no training direction uses its nearest ancestor that holds one. Call before
        training on sparse measurements."""
        n = self.cfg.nside
        for south, w, name in ((False, wi, "wi"), (True, wo, "wo")):
            check_directions(w, f"NeuBRDF.prune {name}")
            sup = hpx.supervised_pixels(n, hpx.hemisphere_direction(w, south))
            getattr(self, "level_o" if south else "level_i").copy_(hpx.pruned_levels(n, sup).to(torch.int8))
        self._pixel_features = None

    def used_slots(self) -> torch.Tensor:
        """Mask (2 n,) of grid slots referenced by some pixel of the (pruned) grids."""
        n = self.cfg.nside
        mask = torch.zeros(2 * hpx.hemisphere_size(n), dtype=torch.bool, device=self.level_i.device)
        pix = torch.arange(12 * n * n, device=mask.device)
        z = hpx.pix2vec(n, pix)[:, 2].to(mask.device)
        for south, level, keep in ((False, self.level_i, z >= -1e-12), (True, self.level_o, z <= 1e-12)):
            p = pix[keep]
            vid = hpx.ancestor_corner_vertices(n, p, level[p].long())
            mask[vid + hpx.south_grid_offset(n) if south else vid] = True
        return mask

    @property
    def is_runtime(self) -> bool:
        """Whether `runtime()` is in effect (model files record it and re-enter runtime mode on load)."""
        return self._pixel_features is not None

    def freeze(self) -> None:
        """Freeze the vertex features to integers (indices or low-bit codes) for export."""
        self.grid.freeze()
        self._pixel_features = None

    def train(self, mode: bool = True) -> "NeuBRDF":
        """torch train / inference switch; training drops the runtime cache (it would go stale)."""
        if mode:
            self._pixel_features = None
        return super().train(mode)

    @torch.no_grad()
    def runtime(self) -> "NeuBRDF":
        """Switch to the paper's runtime mode: frozen indices, 1/4 weights, per-pixel feature cache."""
        self.freeze()
        self.cfg = replace(self.cfg, interpolation="uniform")
        n = self.cfg.nside
        pix = torch.arange(12 * n * n, device=self.level_i.device)
        tables = []
        for south, level in ((False, self.level_i), (True, self.level_o)):
            vid = hpx.ancestor_corner_vertices(n, pix, level.long())
            ok = (vid >= hpx.nvertices(n) - hpx.hemisphere_size(n)) if south else (vid < hpx.hemisphere_size(n))
            slots = (vid + hpx.south_grid_offset(n) if south else vid).clamp(0, 2 * hpx.hemisphere_size(n) - 1)
            # pixels outside the hemisphere are never looked up; their entries are left at 0
            tables.append(torch.where(ok.all(-1, keepdim=True), self.grid(slots).mean(1), 0.0))
        self._pixel_features = (tables[0], tables[1])
        return self.train(False)

    # ------------------------------------------------------------------------------------ storage

    def grid_size_bytes(self, precision: str = "fp16") -> int:
        """Bytes of the spherical grid: b-bit indices of the 2 n slots plus the 2^b x k codebook
        (vq; the paper's formula 2 n b + p k 2^b bits), or the dense / low-bit features."""
        return storage_bytes(self.grid.storage_bits(float_bits(precision)))

    def size_bytes(self, precision: str = "fp16") -> int:
        """Stored size: grid (see `grid_size_bytes`) + MLP weights and biases + neural texture, floats at
        `precision`. The pruning levels are not counted (the paper counts the full grid)."""
        fb = float_bits(precision)
        floats = self.mlp.num_parameters() + (self.texture.num_parameters() if self.texture is not None else 0)
        return storage_bytes(self.grid.storage_bits(fb) + floats * fb)

    def flops(self) -> int:
        """MLP floating-point operations per evaluation (feature lookups not counted)."""
        return self.mlp.flops()
