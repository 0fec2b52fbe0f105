"""Feature storage on grid vertices: codebook indices learned end to end (VQ-AD), dense, or low-bit.

`VQFeatures` follows variable-bitrate neural fields (Takikawa et al. 2022, VQ-AD), which NeuBRDF
(Dou et al. 2024, Sec. 3.3) uses: every vertex stores a b-bit index into a codebook D (2^b, k). While
training, each vertex holds logits over the 2^b entries (dense, exactly as VQ-AD; 2n x 2^b floats, i.e.
49922 x 512 = 25.6 M floats = 102 MB fp32, about 0.3 GB with Adam state, at the NeuBRDF defaults); the
forward pass returns the codebook row of the argmax index, the codebook gets the gradient of that hard
lookup, and the logits get the gradient of the softmax mixture (straight-through estimator, as in
kaolin-wisp's CodebookOctreeGrid). `freeze()` replaces the logits by the integer indices.

Details: src/neumat/methods/neubrdf/NOTES.md, section `neumat.nn.codebook`.
"""
from __future__ import annotations

import math

import torch
from torch import nn
from torch.autograd.function import once_differentiable

from neumat.core.checks import check_int
from neumat.core.errors import InputError
from neumat.nn.packing import pack_bits, unpack_bits

FLOAT_BITS = {"fp16": 16, "fp32": 32}


def float_bits(precision: str) -> int:
    """Bits per stored float of a precision name ("fp16" or "fp32")."""
    if precision not in FLOAT_BITS:
        raise InputError(f"precision: expected one of {', '.join(FLOAT_BITS)}, got {precision!r}")
    return FLOAT_BITS[precision]


def _check_ids(ids: torch.Tensor, n: int) -> None:
    if not isinstance(ids, torch.Tensor) or ids.dtype.is_floating_point or ids.dtype == torch.bool:
        raise InputError("ids: expected an integer tensor of vertex ids")
    if ids.numel() and (ids.min().item() < 0 or ids.max().item() >= n):
        raise InputError(f"ids: vertex ids must lie in [0, {n})")


def scratch(store: dict, name: str, rows: int, cols: int, like: torch.Tensor) -> torch.Tensor:
    """A reusable (rows, cols) buffer `store[name]` with `like`'s dtype and device, grown by 1/4 when short.

    Why: a fresh tensor over glibc's mmap threshold (32 MB) is mapped anew on every allocation, and its
    page faults cost about as much as a pass of arithmetic over it (~25 ms for 32k x 512 floats on one
    CPU thread); a training step of a VQ grid at N_side 64 makes several such temporaries. Only for
    temporaries that do not outlive the call that fills them."""
    buf = store.get(name)
    if buf is None or buf.dtype != like.dtype or buf.device != like.device or buf.numel() < rows * cols:
        buf = store[name] = torch.empty(max(rows * cols, int(rows * cols * 1.25)), dtype=like.dtype,
                                        device=like.device)
    return buf[:rows * cols].view(rows, cols)


class _StraightThrough(torch.autograd.Function):
    """out = D[c(argmax l)] (U, k) of the logit rows l = L[uniq] (U, K) of the logits L (V, K), c the row's
    candidate codewords (`candidates` (V, K) int64, or None: all 2^b, K = 2^b, c the identity); backward: D
    gets the gradient of the hard lookup, l that of softmax(l) @ D[c] with D held fixed: s * (g D[c]^T -
    <g, s D[c]>) per row, s = softmax(l). L gets that row gradient on rows `uniq` (sorted, unique:
    `torch.unique`), as a sparse, already coalesced gradient when `sparse` (no coalescing or dense V x K
    gradient), else dense. The rows live in `store` scratch memory, gathered again in the backward pass if
    another call used it since (the logits themselves are saved: autograd rejects a backward pass after they
    changed in place)."""

    @staticmethod
    def forward(ctx, logits: torch.Tensor, codebook: torch.Tensor, uniq: torch.Tensor,
                candidates: torch.Tensor | None, sparse: bool, store: dict) -> torch.Tensor:
        rows = torch.index_select(logits, 0, uniq, out=scratch(store, "rows", uniq.shape[0], logits.shape[1],
                                                               logits))
        best = rows.argmax(-1)
        idx = best if candidates is None else candidates[uniq, best]
        ctx.save_for_backward(logits, codebook, uniq, idx, candidates)
        ctx.sparse, ctx.store = sparse, store
        ctx.token = store["rows_of"] = object()  # the scratch rows are this call's until the next forward
        return codebook[idx]

    @staticmethod
    @once_differentiable
    def backward(ctx, g: torch.Tensor):
        logits, codebook, uniq, idx, candidates = ctx.saved_tensors
        grad_logits = grad_code = None
        if ctx.needs_input_grad[0]:
            rows = scratch(ctx.store, "rows", uniq.shape[0], logits.shape[1], logits)
            if ctx.store.get("rows_of") is not ctx.token:  # another forward pass used the scratch rows since
                torch.index_select(logits, 0, uniq, out=rows)
            ctx.store["rows_of"] = None  # overwritten below
            s = torch.softmax(rows, -1, out=scratch(ctx.store, "soft", *rows.shape, rows))
            if candidates is None:
                gd = g @ codebook.t()
            else:  # <g, D[c_j]> for the row's K candidates c_j
                gd = _candidate_products(g, codebook, candidates[uniq])
            gd.sub_(torch.mul(s, gd, out=rows).sum(-1, keepdim=True))
            gd.mul_(s)
            if ctx.sparse:
                grad_logits = torch.sparse_coo_tensor(uniq.unsqueeze(0), gd, logits.shape,
                                                      is_coalesced=True, check_invariants=False)
            else:
                grad_logits = torch.zeros_like(logits).index_copy_(0, uniq, gd)
        if ctx.needs_input_grad[1]:
            grad_code = torch.zeros_like(codebook).index_add_(0, idx, g)
        return grad_logits, grad_code, None, None, None, None


def _candidate_products(g: torch.Tensor, codebook: torch.Tensor, cand: torch.Tensor,
                        chunk: int = 4096) -> torch.Tensor:
    """<g_u, D[cand_uj]> (U, K) for gradients g (U, k), codebook D (2^b, k), candidates (U, K) int64: the
    candidate rows gathered with `index_select` and multiplied with `bmm`, on row chunks that stay in cache
    (on one CPU thread at U = 32k, k = 16: 7 ms for K = 8, 32 ms for K = 32; advanced indexing of the whole
    (U, K, k) array took 250 ms, and (g D^T) gathered at the candidates 22-38 ms)."""
    out = torch.empty(cand.shape, dtype=g.dtype, device=g.device)
    for s in range(0, g.shape[0], chunk):
        n = min(chunk, g.shape[0] - s)
        rows = codebook.index_select(0, cand[s:s + n].reshape(-1)).view(n, cand.shape[1], -1)
        torch.bmm(rows, g[s:s + n].unsqueeze(-1), out=out[s:s + n].unsqueeze(-1))
    return out


class VQFeatures(nn.Module):
    """k-dim features of `num_vertices` vertices, each a row of a learned codebook (2^bits, dim).

    forward(ids (...,) int) -> (..., dim). Training: straight-through softmax over per-vertex logits, on the
    unique ids of the batch; frozen: integer index lookup. `sparse_grad`: give the logits a sparse row
    gradient (train with `RowAdam`; torch.optim.Adam rejects sparse gradients). After `restrict`, the logits
    are (num_vertices, K) over the codebook rows `candidates` (num_vertices, K) (src/neumat/methods/neubrdf/NOTES.md).
    """

    def __init__(self, num_vertices: int, dim: int, bits: int, init_std: float = 1.0) -> None:
        super().__init__()
        self.num_vertices = check_int(num_vertices, "num_vertices")
        self.dim = check_int(dim, "dim")
        self.bits = check_int(bits, "bits")
        if bits > 16:
            raise InputError(f"bits: expected at most 16 index bits, got {bits}")
        self.codebook = nn.Parameter(torch.randn(2 ** bits, dim) * init_std)
        self.logits = nn.Parameter(torch.randn(num_vertices, 2 ** bits) * 0.01)
        self.register_buffer("candidates", None)
        self.sparse_grad = False
        self._scratch: dict = {}  # reusable temporaries of the training step (see `scratch`)
        self.register_state_dict_post_hook(_pack_index)

    @property
    def frozen(self) -> bool:
        return self.logits is None

    def indices(self) -> torch.Tensor:
        """Current integer index (num_vertices,) of every vertex (argmax of the logits once trained)."""
        return self.index if self.frozen else self._chosen(self.logits.detach().argmax(-1))

    def _chosen(self, best: torch.Tensor, rows: torch.Tensor | None = None) -> torch.Tensor:
        """Codebook rows of the logit columns `best` of the vertices `rows` (default: all)."""
        if self.candidates is None:
            return best
        table = self.candidates if rows is None else self.candidates[rows]
        return table.gather(-1, best.unsqueeze(-1)).squeeze(-1)

    def restrict(self, candidates: torch.Tensor) -> None:
        """Keep per vertex only the logits of its K candidate codewords `candidates` (num_vertices, K) int
        (distinct rows of the codebook per vertex), taken from the current logits, so that each training
        step costs O(K) per vertex instead of O(2^b) (src/neumat/methods/neubrdf/NOTES.md). Build the optimiser again
        afterwards: the logits are a new parameter."""
        if self.frozen:
            raise InputError("VQFeatures.restrict: the indices are frozen")
        if self.candidates is not None:
            raise InputError("VQFeatures.restrict: the candidates are already restricted")
        m = 2 ** self.bits
        if (not isinstance(candidates, torch.Tensor) or candidates.dtype.is_floating_point or candidates.ndim != 2
                or candidates.shape[0] != self.num_vertices or not 1 <= candidates.shape[1] <= m):
            raise InputError(f"VQFeatures.restrict: expected integer candidates ({self.num_vertices}, K) with "
                             f"1 <= K <= {m}, got {getattr(candidates, 'shape', type(candidates).__name__)}")
        cand = candidates.to(self.logits.device, torch.long)
        if cand.numel() and (cand.min() < 0 or cand.max() >= m):
            raise InputError(f"VQFeatures.restrict: candidate codewords must lie in [0, {m})")
        if cand.shape[1] > 1 and bool((cand.sort(-1).values.diff(dim=-1) == 0).any()):
            raise InputError("VQFeatures.restrict: a vertex lists the same candidate codeword twice")
        logits = self.logits.detach().gather(1, cand)
        self.logits = nn.Parameter(logits, requires_grad=self.logits.requires_grad)
        self.candidates = cand

    def freeze(self) -> None:
        """Replace the logits by int32 indices (export / runtime; `state_dict` stores them packed to `bits`
        bits each). Irreversible."""
        if self.frozen:
            return
        idx = self.indices().to(torch.int32)
        self.logits = None
        self.candidates = None
        self.register_buffer("index", idx)

    def forward(self, ids: torch.Tensor) -> torch.Tensor:
        _check_ids(ids, self.num_vertices)
        if self.frozen:
            return self.codebook[self.index[ids].long()]
        uniq, inv = torch.unique(ids, return_inverse=True)
        if not torch.is_grad_enabled():
            return self.codebook[self._chosen(self.logits[uniq].argmax(-1), uniq)][inv]
        return _StraightThrough.apply(self.logits, self.codebook, uniq, self.candidates, self.sparse_grad,
                                      self._scratch)[inv]

    def storage_bits(self, float_bits: int) -> int:
        """Index bits plus codebook floats: V b + float_bits k 2^b."""
        return self.num_vertices * self.bits + float_bits * self.dim * 2 ** self.bits

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs):
        if prefix + "packed_index" in state_dict:  # the frozen form of `state_dict` (`_pack_index`)
            packed = state_dict.pop(prefix + "packed_index")
            state_dict[prefix + "index"] = unpack_bits(packed, self.bits, self.num_vertices,
                                                       f"{prefix}packed_index").to(torch.int32)
        if prefix + "index" in state_dict and not self.frozen:  # loading an exported (frozen) model
            self.logits = None
            self.candidates = None
            self.register_buffer("index", torch.zeros(self.num_vertices, dtype=torch.int32))
        cand = state_dict.get(prefix + "candidates")
        if cand is not None and not self.frozen and self.candidates is None:  # a restricted training state
            self.restrict(torch.arange(cand.shape[1]).repeat(cand.shape[0], 1))  # shape only: the load fills it
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)


def _pack_index(module: VQFeatures, state_dict: dict, prefix: str, local_metadata) -> None:
    """State-dict hook: a frozen grid stores its indices packed, `bits` bits each (`pack_bits`), as
    "packed_index"; loading unpacks them (older files with an int32 "index" load too)."""
    if module.frozen:
        state_dict[prefix + "packed_index"] = pack_bits(state_dict.pop(prefix + "index"), module.bits)

class DenseFeatures(nn.Module):
    """Features stored directly, (num_vertices, dim) floats (the 'w/o quantization' ablation)."""

    def __init__(self, num_vertices: int, dim: int, init_std: float = 0.1) -> None:
        super().__init__()
        self.num_vertices = check_int(num_vertices, "num_vertices")
        self.dim = check_int(dim, "dim")
        self.features = nn.Parameter(torch.randn(num_vertices, dim) * init_std)

    @classmethod
    def holding(cls, feats: torch.Tensor, requires_grad: bool = True) -> "DenseFeatures":
        """A grid of feats.shape[0] vertices holding the features `feats` (V, k), on their device and dtype."""
        grid = cls(feats.shape[0], feats.shape[1]).to(feats.device, feats.dtype)
        with torch.no_grad():
            grid.features.copy_(feats)
        return grid.requires_grad_(requires_grad)

    def forward(self, ids: torch.Tensor) -> torch.Tensor:
        _check_ids(ids, self.num_vertices)
        return self.features[ids]

    def freeze(self) -> None:
        """Nothing to freeze: dense features are stored as they are."""

    def storage_bits(self, float_bits: int) -> int:
        return self.num_vertices * self.dim * float_bits


class LowBitFeatures(nn.Module):
    """Dense features quantised to `feature_bits` uniform levels on [-1, 1] (the 'low-bit' ablation).

    Training simulates the quantisation with a straight-through rounding (as in neural image / texture
    compression); `freeze()` stores the integer codes (uint8).
    """

    def __init__(self, num_vertices: int, dim: int, feature_bits: int, init_std: float = 0.1) -> None:
        super().__init__()
        self.num_vertices = check_int(num_vertices, "num_vertices")
        self.dim = check_int(dim, "dim")
        self.feature_bits = check_int(feature_bits, "feature_bits")
        if feature_bits > 8:
            raise InputError(f"feature_bits: expected at most 8 bits, got {feature_bits}")
        self.levels = 2 ** feature_bits - 1
        self.features = nn.Parameter((torch.randn(num_vertices, dim) * init_std).clamp(-1, 1))

    @property
    def frozen(self) -> bool:
        return self.features is None

    def _codes(self, x: torch.Tensor) -> torch.Tensor:
        return torch.round((x.clamp(-1, 1) + 1) * (self.levels / 2))

    def _decode(self, codes: torch.Tensor) -> torch.Tensor:
        return codes * (2 / self.levels) - 1

    def forward(self, ids: torch.Tensor) -> torch.Tensor:
        _check_ids(ids, self.num_vertices)
        if self.frozen:
            return self._decode(self.codes[ids].float())
        x = self.features[ids].clamp(-1, 1)
        return x + (self._decode(self._codes(x)) - x).detach()

    def freeze(self) -> None:
        """Replace the float features by their uint8 codes. Irreversible."""
        if self.frozen:
            return
        codes = self._codes(self.features.detach()).to(torch.uint8)
        self.features = None
        self.register_buffer("codes", codes)

    def storage_bits(self, float_bits: int) -> int:
        return self.num_vertices * self.dim * self.feature_bits

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs):
        if prefix + "codes" in state_dict and not self.frozen:
            self.features = None
            self.register_buffer("codes", torch.zeros(self.num_vertices, self.dim, dtype=torch.uint8))
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)


def storage_bytes(bits: int) -> int:
    """Bytes needed for `bits` bits."""
    return math.ceil(bits / 8)
