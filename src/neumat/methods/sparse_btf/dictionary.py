"""SparseBTF building blocks (Kavoosi et al. 2023, Sec. 3.1-3.3): BTF data points, the ensemble of
orthonormal 4D dictionaries, sparse coding (Eq. 3), reconstruction (Eq. 4) and dictionary files. Training
the ensemble (Eq. 2) is training code, in the fit package (methods/sparse_btf/dictionary_train.py, and the "dictionary"
phase of the sparse-btf recipe).

Details: src/neumat/methods/sparse_btf/NOTES.md, section `neumat.methods.sparse_btf.dictionary`.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import torch

from neumat.core.errors import DataFormatError, InputError
from neumat.io.tagged_file import header_field, read_tagged, write_tagged

#: RGB -> YUV (BT.601 analogue), rows Y, U, V
RGB_TO_YUV = torch.tensor([[0.299, 0.587, 0.114],
                           [-0.14713, -0.28886, 0.436],
                           [0.615, -0.51499, -0.10001]], dtype=torch.float64)
YUV_TO_RGB = torch.linalg.inv(RGB_TO_YUV)
#: standard deviations below this are treated as 1 (constant angular images, e.g. fully shadowed)
MIN_STD = 1e-6


# ----------------------------------------------------------------------------------------- transforms
def rgb_to_model_space(data: torch.Tensor, eps: float) -> torch.Tensor:
    """log(max(x, 0) + eps) then RGB -> YUV, on the last axis (..., 3)."""
    logd = torch.log(data.clamp(min=0) + eps)
    return logd @ RGB_TO_YUV.to(logd).T


def model_space_to_rgb(yuv: torch.Tensor, eps: float) -> torch.Tensor:
    """Inverse of `rgb_to_model_space`; values that approximation errors push below 0 are clamped to 0 (a BTF
    value is non-negative, and the forward transform clamps the same way)."""
    return (torch.exp(yuv @ YUV_TO_RGB.to(yuv).T) - eps).clamp(min=0)


#: what the standardisation statistics are taken over: every angular image (the paper) or the whole BTF
STATISTICS = ("image", "btf")


def image_statistics(yuv: torch.Tensor, statistics: str = "image") -> tuple[torch.Tensor, torch.Tensor]:
    """Mean and std (L, V, 3) of yuv (L, V, H, W, 3) per angular image and channel (statistics "image", Sec.
    3.1), or per channel over the whole BTF, repeated over the images ("btf": 6 numbers to store)."""
    if statistics not in STATISTICS:
        raise InputError(f"SparseBTF statistics: expected one of {STATISTICS}, got {statistics!r}")
    dims = (2, 3) if statistics == "image" else (0, 1, 2, 3)
    mean = yuv.mean(dim=dims, keepdim=True)
    std = yuv.std(dim=dims, unbiased=False, keepdim=True)
    std = torch.where(std > MIN_STD, std, torch.ones_like(std))
    shape = (yuv.shape[0], yuv.shape[1], yuv.shape[-1])
    return (mean.reshape(-1, mean.shape[1], 3).expand(shape).clone(),
            std.reshape(-1, std.shape[1], 3).expand(shape).clone())


def to_data_points(z: torch.Tensor, patch: int) -> torch.Tensor:
    """Standardised (L, V, H, W, 3) -> data points (3, P, p, p, L, V), patches in row-major order."""
    l, v, h, w, c = z.shape
    check_patch_grid(h, w, patch)
    x = z.reshape(l, v, h // patch, patch, w // patch, patch, c)
    return x.permute(6, 2, 4, 3, 5, 0, 1).reshape(c, (h // patch) * (w // patch), patch, patch, l, v)


def from_data_points(points: torch.Tensor, height: int, width: int) -> torch.Tensor:
    """Inverse of `to_data_points`: (3, P, p, p, L, V) -> (L, V, H, W, 3)."""
    c, _, p, _, l, v = points.shape
    x = points.reshape(c, height // p, width // p, p, p, l, v)
    return x.permute(5, 6, 1, 3, 2, 4, 0).reshape(l, v, height, width, c)


def check_patch_grid(height: int, width: int, patch: int) -> None:
    """Raise unless the H x W texels split into whole p x p patches."""
    if patch < 1 or height % patch or width % patch:
        raise InputError(f"SparseBTF: the BTF's {height} x {width} texels do not split into {patch} x {patch} "
                         "patches; crop or resample it to a multiple of the patch size")


# ----------------------------------------------------------------------------------------- tensor algebra
def mode_product(x: torch.Tensor, u: torch.Tensor, mode: int) -> torch.Tensor:
    """x (N, m1, ..., m4) times_mode u: multiplies every mode-`mode` fibre (mode 1..4) by u (m_out, m_in).
    u may also be (N, m_out, m_in), one matrix per point. Computed as u @ x viewed as (N, A, m_in, B),
    which needs no transposed copy of x; for the last mode (B = 1) as x viewed as (N, A, m_in) @ u^T, one
    matrix product instead of N A matrix-vector products (18x faster at 151 x 151 directions)."""
    shape = x.shape
    a, b = math.prod(shape[1:mode]), math.prod(shape[mode + 1:])
    if b == 1:
        out = x.reshape(shape[0], a, shape[mode]) @ u.transpose(-1, -2)
    else:
        out = (u if u.dim() == 2 else u[:, None]) @ x.reshape(shape[0], a, shape[mode], b)
    return out.reshape(*shape[:mode], u.shape[-2], *shape[mode + 1:])


def project(x: torch.Tensor, mats: list[torch.Tensor]) -> torch.Tensor:
    """Coefficients S = x x_1 U1^T x_2 U2^T x_3 U3^T x_4 U4^T (Eq. 3); mats (m_n, m_n) or (N, m_n, m_n)."""
    for n, u in enumerate(mats, start=1):
        x = mode_product(x, u.transpose(-1, -2), n)
    return x


def reconstruct(s: torch.Tensor, mats: list[torch.Tensor]) -> torch.Tensor:
    """Data points x = S x_1 U1 x_2 U2 x_3 U3 x_4 U4 (Eq. 4)."""
    for n, u in enumerate(mats, start=1):
        s = mode_product(s, u, n)
    return s


def keep_largest(s: torch.Tensor, tau: int, threshold: float = 0.0
                 ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Sparsify coefficients s (N, M) of orthonormal bases.

    Keeps the tau largest |s| per point, or fewer: as few as make the mean squared error per element
    (||x||^2 - sum kept s^2) / M fall to `threshold` (at least one). Returns values (N, tau) (zero beyond
    the count), flat indices (N, tau), counts (N,) and the mean squared errors (N,).
    """
    n, m = s.shape
    tau = min(tau, m)
    vals, idx = s.abs().topk(tau, dim=-1)
    vals = s.gather(1, idx)
    total = (s * s).sum(-1)
    kept = (vals * vals).cumsum(-1)
    err = (total[:, None] - kept).clamp(min=0) / m
    if threshold > 0:
        reached = err <= threshold
        counts = torch.where(reached.any(-1), reached.float().argmax(-1) + 1, torch.full_like(total, tau).long())
    else:
        counts = torch.full((n,), tau, dtype=torch.long, device=s.device)
    live = torch.arange(tau, device=s.device)[None, :] < counts[:, None]
    vals = torch.where(live, vals, torch.zeros_like(vals))
    final_err = err.gather(1, (counts - 1)[:, None])[:, 0]
    return vals, idx, counts, final_err


def unravel(flat: torch.Tensor, shape: tuple[int, ...]) -> torch.Tensor:
    """Flat indices (...) into a tensor of `shape` -> index tuples (..., len(shape))."""
    out = []
    for size in reversed(shape):
        out.append(flat % size)
        flat = torch.div(flat, size, rounding_mode="floor")
    return torch.stack(out[::-1], -1)


# ----------------------------------------------------------------------------------------- the ensemble
@dataclass
class Ensemble:
    """K dictionaries of four orthonormal matrices: mats[n] (K, m_n, m_n), n = 0..3 (modes 1..4)."""

    mats: list[torch.Tensor]

    @property
    def size(self) -> int:
        return self.mats[0].shape[0]

    @property
    def shape(self) -> tuple[int, int, int, int]:
        """(m1, m2, m3, m4) of the data points it codes."""
        return tuple(u.shape[1] for u in self.mats)

    def dictionary(self, k: int) -> list[torch.Tensor]:
        return [u[k] for u in self.mats]

    def orthonormality_error(self) -> float:
        """max |U^T U - I| over all dictionaries and modes."""
        err = 0.0
        for u in self.mats:
            eye = torch.eye(u.shape[1], dtype=u.dtype, device=u.device)
            err = max(err, float((u.transpose(1, 2) @ u - eye).abs().max()))
        return err

    def to(self, device=None, dtype=None) -> "Ensemble":
        return Ensemble([u.to(device=device, dtype=dtype) for u in self.mats])


@dataclass
class Codes:
    """Sparse codes of N data points: membership (N,), values (N, tau), index tuples (N, tau, 4) into the
    coefficient tensor, counts (N,) of live coefficients (values beyond the count are 0) and the mean
    squared error per element (N,) of each point's representation (model space)."""

    membership: torch.Tensor
    values: torch.Tensor
    index: torch.Tensor
    counts: torch.Tensor
    error: torch.Tensor


def code_points(x: torch.Tensor, ensemble: Ensemble, tau: int, threshold: float = 0.0,
                chunk: int | None = None) -> Codes:
    """Sparse codes of data points x (N, m1, m2, m3, m4) (Sec. 3.3): project on every dictionary, keep the
    tau largest coefficients (or stop at `threshold`), pick the sparsest, then lowest-error, dictionary.
    chunk: points projected together (default: about 2^25 coefficients, 128 MB of float32, per chunk)."""
    return code_points_at_rates(x, ensemble, [tau], threshold, chunk)[0]


def code_points_at_rates(x: torch.Tensor, ensemble: Ensemble, taus: Sequence[int], threshold: float = 0.0,
                         chunk: int | None = None) -> list[Codes]:
    """`code_points` for every tau of `taus`, projecting each data point on each dictionary once: only the
    top-k selection and the choice of dictionary depend on tau. Returns one Codes per tau, in order."""
    if tuple(x.shape[1:]) != ensemble.shape:
        raise InputError(f"SparseBTF: data points have shape {tuple(x.shape[1:])} but the dictionary ensemble was "
                         f"trained for {ensemble.shape} (patch, patch, lights, views); a dictionary only codes "
                         "BTFs of the angular resolution and patch size it was trained on (paper, Sec. 5)")
    if not taus:
        raise InputError("SparseBTF: no coefficient count tau given")
    n = x.shape[0]
    m = math.prod(ensemble.shape)
    taus = [min(int(t), m) for t in taus]
    chunk = chunk or max(1, (1 << 25) // m)
    parts = [[] for _ in taus]
    for s in range(0, n, chunk):
        xc = x[s:s + chunk]
        best = [None] * len(taus)
        for k in range(ensemble.size):
            coeffs = project(xc, ensemble.dictionary(k)).reshape(xc.shape[0], -1)
            for r, tau in enumerate(taus):
                best[r] = _keep_better(best[r], k, *keep_largest(coeffs, tau, threshold))
        for r in range(len(taus)):
            parts[r].append(best[r])
    out = []
    for p in parts:
        memb, vals, idx, counts, err = (torch.cat([c[i] for c in p]) for i in range(5))
        out.append(Codes(memb, vals, unravel(idx, ensemble.shape), counts, err))
    return out


def _keep_better(best: list | None, k: int, vals: torch.Tensor, idx: torch.Tensor, counts: torch.Tensor,
                 err: torch.Tensor) -> list:
    """Per point, the sparser (then lower-error) of the codes in `best` [membership, vals, idx, counts, err]
    and dictionary k's codes."""
    if best is None:
        return [torch.full_like(counts, k), vals, idx, counts, err]
    better = (counts < best[3]) | ((counts == best[3]) & (err < best[4]))
    return [torch.where(better, torch.full_like(counts, k), best[0]),
            torch.where(better[:, None], vals, best[1]),
            torch.where(better[:, None], idx, best[2]),
            torch.where(better, counts, best[3]),
            torch.where(better, err, best[4])]


def dense_coefficients(codes: Codes, shape: tuple[int, ...]) -> torch.Tensor:
    """Dense coefficient tensors (N, m1, m2, m3, m4) of sparse codes."""
    n = codes.values.shape[0]
    flat = torch.zeros(n, math.prod(shape), dtype=codes.values.dtype, device=codes.values.device)
    strides = torch.tensor([math.prod(shape[i + 1:]) for i in range(len(shape))], device=codes.index.device)
    flat_idx = (codes.index * strides).sum(-1)
    flat.scatter_add_(1, flat_idx, codes.values)
    return flat.reshape(n, *shape)


def decode_points(codes: Codes, ensemble: Ensemble) -> torch.Tensor:
    """Reconstructed data points (N, m1, m2, m3, m4) (Eq. 4), grouped by dictionary."""
    s = dense_coefficients(codes, ensemble.shape)
    out = torch.empty_like(s)
    for k in range(ensemble.size):
        sel = codes.membership == k
        if bool(sel.any()):
            out[sel] = reconstruct(s[sel], ensemble.dictionary(k))
    return out


# ----------------------------------------------------------------------------------------- dictionary files
@dataclass
class BTFDictionary:
    """Three ensembles (Y, U, V) trained once, plus what a BTF must match to be coded with them.

    light_dirs (L, 3), view_dirs (V, 3): the angular sampling; patch: p; tau_train: (tau_Y, tau_U, tau_V);
    log_eps: eps of the log transform; log: training objective history per channel, seconds.
    """

    ensembles: list[Ensemble]
    light_dirs: torch.Tensor
    view_dirs: torch.Tensor
    patch: int
    tau_train: tuple[int, int, int]
    log_eps: float
    info: dict = field(default_factory=dict)

    @property
    def num_dictionaries(self) -> int:
        return self.ensembles[0].size

    def check_compatible(self, light_dirs: torch.Tensor, view_dirs: torch.Tensor, what: str = "BTF") -> None:
        """Refuse a BTF sampled at other directions (the paper's stated limitation, Sec. 5)."""
        for name, mine, theirs in (("light", self.light_dirs, light_dirs), ("view", self.view_dirs, view_dirs)):
            if mine.shape != theirs.shape:
                raise InputError(f"{what} has {theirs.shape[0]} {name} directions but the dictionary was trained for "
                                 f"{mine.shape[0]}; SparseBTF dictionaries only code BTFs of the angular resolution "
                                 "they were trained on: train a dictionary for this direction set")
            if float((mine.to(theirs) - theirs).abs().max()) > 1e-4:
                raise InputError(f"{what}'s {name} directions differ from the dictionary's (same count, other "
                                 "directions); train a dictionary for this direction set")

    def save(self, path: str | Path) -> Path:
        """Write a `.nmat`-style file: safetensors tensors plus a JSON header (type "btf-dictionary")."""
        from neumat.core.version import __version__
        tensors = {"light_dirs": self.light_dirs.float(), "view_dirs": self.view_dirs.float()}
        for c, ens in enumerate(self.ensembles):
            for j, u in enumerate(ens.mats):
                tensors[f"U{j + 1}_{'YUV'[c]}"] = u.float()
        header = {"type": "btf-dictionary", "patch": self.patch, "tau_train": list(self.tau_train),
                  "log_eps": self.log_eps, "num_dictionaries": self.num_dictionaries, "info": self.info,
                  "neumat_version": __version__}
        return write_tagged(path, tensors, header)

    @classmethod
    def load(cls, path: str | Path, device=None) -> "BTFDictionary":
        """Read a file written by `save`, or a dictionary shipped with the package by its name
        (`SHIPPED_DICTIONARIES`, e.g. "default")."""
        path = shipped_dictionary(path) or path
        meta, tensors = read_tagged(path, "btf-dictionary", "dictionary")
        try:
            ens = [Ensemble([tensors[f"U{j + 1}_{ch}"].to(device) for j in range(4)]) for ch in "YUV"]
        except KeyError as e:
            raise DataFormatError(f"{path}: missing dictionary tensor {e}") from None
        for k in ("light_dirs", "view_dirs"):
            if k not in tensors:
                raise DataFormatError(f"{path}: missing dictionary tensor {k!r}")
        where = f"{path}: header"
        return cls(ens, tensors["light_dirs"].to(device), tensors["view_dirs"].to(device),
                   header_field(meta, "patch", "a positive integer", where),
                   tuple(header_field(meta, "tau_train", "a list of finite numbers", where)),
                   float(header_field(meta, "log_eps", "a finite number", where)),
                   header_field(meta, "info", "a JSON object", where, default={}))


#: dictionaries shipped with the package: name -> file under neumat/methods/sparse_btf/data (docs/btf.md,
#: "Shipped dictionary")
SHIPPED_DICTIONARIES = {"default": "sparse_btf_rings3x30.nmat"}


def shipped_dictionary(name: str | Path) -> Path | None:
    """The file of a shipped dictionary called `name`, or None when `name` names none (then it is a path)."""
    if str(name) not in SHIPPED_DICTIONARIES:
        return None
    return Path(__file__).parent / "data" / SHIPPED_DICTIONARIES[str(name)]


def prepare_btf(data: torch.Tensor, patch: int, log_eps: float, statistics: str = "image"
                ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """BTF data (L, V, H, W, 3) -> data points (3, P, p, p, L, V), mean and std (L, V, 3) (Sec. 3.1;
    `image_statistics` for `statistics`)."""
    yuv = rgb_to_model_space(data.float(), log_eps)
    mean, std = image_statistics(yuv, statistics)
    z = (yuv - mean[:, :, None, None, :]) / std[:, :, None, None, :]
    return to_data_points(z, patch), mean, std
