"""NBRDF (Sztrajman, Rainer, Ritschel, Weyrich, CGF 2021): one tiny MLP per material on the
Rusinkiewicz half and difference vectors.

Input: h = normalize(wi + wo) and d = wi in the frame where h is the pole, both Cartesian
(hx, hy, hz, dx, dy, dz), exactly the 6 inputs of the authors' code (`Xvars`). Network 6-21-21-3 with
ReLU; output transform of their code: f = max(exp(x) - 1, 0) (their comment: "additional relu is
max() op as in code in nn.h"), which gives an exact 0 where the network output is negative. Weights
start uniform in [-0.05, 0.05], biases at 0, as theirs. Their loss and schedule are in
`neumat.methods.baselines.nbrdf_train`.

Details: src/neumat/methods/neubrdf/NOTES.md, section `neumat.methods.baselines.nbrdf`.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from neumat.core.checks import check_int
from neumat.core.config import resolve_config
from neumat.core.coords import hd_vectors
from neumat.core.errors import InputError
from neumat.core.material import zero_below_horizon
from neumat.core.query import Query
from neumat.core.tensors import by_rows, inference_call
from neumat.models.base import LearnedMaterial
from neumat.nn import cpu_kernels
from neumat.nn.codebook import float_bits, storage_bytes
from neumat.nn.mlp import MLP

OUTPUTS = ("exp_minus_one", "exp")
HALF_INPUTS = ("vector", "theta")


@dataclass
class Config:
    """NBRDF hyper-parameters; defaults are the authors' (paper Sec. 4 and their PyTorch code)."""

    hidden: int = 21
    """Neurons per hidden layer."""
    hidden_layers: int = 2
    """Number of hidden layers."""
    activation: str = "relu"
    """Hidden activation."""
    output: str = "exp_minus_one"
    """Output transform: "exp_minus_one" (max(exp(x) - 1, 0), the authors' code) or "exp"."""
    init_range: float = 0.05
    """Weights are initialised uniform in [-init_range, init_range], biases at 0 (authors' code)."""
    half: str = "vector"
    """Half-vector input: "vector" (hx, hy, hz) or "theta" ((sin theta_h, 0, cos theta_h), phi_h dropped, as
    the authors' training data and renderer)."""
    fold_phi_d: bool = False
    """Mirror d to (-dx, -dy, dz) where dy < 0 (phi_d into [0, pi), MERL's half range): makes eval reciprocal."""


def _check_config(c: Config) -> None:
    for name, lo in (("hidden", 1), ("hidden_layers", 0)):
        check_int(getattr(c, name), f"NBRDF.{name}", lo)
    if c.output not in OUTPUTS:
        raise InputError(f"NBRDF.output: expected one of {', '.join(OUTPUTS)}, got {c.output!r}")
    if c.half not in HALF_INPUTS:
        raise InputError(f"NBRDF.half: expected one of {', '.join(HALF_INPUTS)}, got {c.half!r}")
    if not isinstance(c.fold_phi_d, bool):
        raise InputError(f"NBRDF.fold_phi_d: expected a bool, got {c.fold_phi_d!r}")
    if not c.init_range > 0:
        raise InputError(f"NBRDF.init_range: expected a positive number, got {c.init_range!r}")


class NBRDF(LearnedMaterial):
    """out(MLP([h, d])) with the Rusinkiewicz half / difference vectors (see module docstring)."""

    name = "nbrdf"
    paper = "NBRDF (Sztrajman et al. 2021): baseline of NeuBRDF"
    source_kinds = ("brdf",)
    can_sample = False
    Config = Config

    def __init__(self, config: Config | None = None, **kwargs) -> None:
        nn.Module.__init__(self)
        cfg = resolve_config(Config, config, kwargs, 'NBRDF')
        _check_config(cfg)
        self.cfg = cfg
        self.mlp = MLP(6, cfg.hidden, cfg.hidden_layers, 3, cfg.activation)
        with torch.no_grad():
            for lin in self.mlp.linears():
                lin.weight.uniform_(-cfg.init_range, cfg.init_range)
                lin.bias.zero_()

    @property
    def config(self) -> Config:
        return self.cfg

    @staticmethod
    def encode(wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
        """Network input (N, 6): (hx, hy, hz, dx, dy, dz) of directions wi, wo (N, 3) (`hd_vectors`)."""
        h, d = hd_vectors(wi, wo)
        return torch.cat([h, d], -1)

    def inputs(self, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
        """Network input (N, 6) under this model's `half` and `fold_phi_d` options (defaults: `encode`)."""
        h, d = hd_vectors(wi, wo)
        if self.cfg.half == "theta":
            h = torch.stack([torch.sqrt(h[:, 0] ** 2 + h[:, 1] ** 2), torch.zeros_like(h[:, 0]), h[:, 2]], -1)
        if self.cfg.fold_phi_d:
            d = torch.where((d[:, 1] < 0).unsqueeze(-1), d * d.new_tensor([-1.0, -1.0, 1.0]), d)
        return torch.cat([h, d], -1)

    @classmethod
    def from_keras(cls, h5_path, json_path=None, fold_phi_d: bool = True,
                   dtype: torch.dtype = torch.float64) -> "NBRDF":
        """The authors' published network (`NAME.h5` + `NAME.json`, see `neumat.io.nbrdf_keras`).

        eval is f = max(exp(W3 relu(W2 relu(W1 x + b1) + b2) + b3) - 1, 0), x = (sin theta_h, 0, cos theta_h,
        dx, dy, dz), d of wi (towards the light), 0 below the horizon: their renderer's `Net::forward`. Values
        are BRDF values (MERL's per-channel scale already inside: they trained on scaled MERL values).
        fold_phi_d: see `Config.fold_phi_d` (True: reciprocal; False: their raw function for every phi_d).
        dtype: of the weights (float64 default: float32 file values, evaluated without float32 rounding)."""
        from neumat.io.nbrdf_keras import read_nbrdf_keras

        net = read_nbrdf_keras(h5_path, json_path)
        hidden = set(net.dims[1:-1])
        if (net.dims[0], net.dims[-1]) != (6, 3) or len(hidden) != 1 or \
                net.activations != ["relu"] * (len(net.dims) - 2) + ["linear"] or net.output != "exp_minus_one":
            from neumat.core.errors import DataFormatError
            raise DataFormatError(f"{h5_path}: expected an NBRDF network 6-n-..-n-3 (relu, linear, exp(x) - 1), got "
                                  f"{'-'.join(map(str, net.dims))} {net.activations} output {net.output}")
        model = cls(hidden=hidden.pop(), hidden_layers=len(net.dims) - 2, activation="relu",
                    output="exp_minus_one", half="theta", fold_phi_d=fold_phi_d).to(dtype)
        with torch.no_grad():
            for lin, k, b in zip(model.mlp.linears(), net.kernels, net.biases):
                lin.weight.copy_(torch.from_numpy(k.T.copy()))
                lin.bias.copy_(torch.from_numpy(b))
        return model

    def eval(self, q: Query) -> torch.Tensor:
        """BRDF value (N, 3), linear RGB, cosine excluded; 0 below the horizon."""
        q.require("wo", who="NBRDF.eval")
        if cpu_kernels.usable(q.wi, q.wo, self.mlp.net[0].weight):
            mlp = cpu_kernels.prepared(self, lambda: cpu_kernels.PackedMLP.pack(self.mlp.net))
            if mlp is not None:  # one fused C call (neumat.nn.cpu_kernels); the same values as the torch path
                return cpu_kernels.nbrdf_eval(mlp, q.wi, q.wo, self.cfg.half == "theta", self.cfg.fold_phi_d,
                                              self.cfg.output == "exp_minus_one")
        return inference_call(self._eval_by_rows, q.wi, q.wo)

    def _eval_by_rows(self, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
        return by_rows(self._eval, self.eval_chunk, wi, wo)

    def _eval(self, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
        """`eval` of directions wi, wo (N, 3), in few tensor operations (a batch of one costs about as many
        microseconds as operations): no dtype conversion where there is none to make, the MLP's layers without
        its input check (`inputs` has 6 columns), exp(x) - 1 as one expm1 (the same value, rounded once)."""
        dtype = self.mlp.net[0].weight.dtype
        out_dtype = wi.dtype
        x = self.mlp.run_layers(self.inputs(wi, wo) if dtype == out_dtype else self.inputs(wi.to(dtype), wo.to(dtype)))
        f = torch.relu(torch.expm1(x)) if self.cfg.output == "exp_minus_one" else torch.exp(x)
        f = zero_below_horizon(f, wi, wo)
        return f if dtype == out_dtype else f.to(out_dtype)

    def forward(self, q: Query) -> torch.Tensor:
        return self.eval(q)

    def size_bytes(self, precision: str = "fp16") -> int:
        """MLP weights and biases at `precision` (6-21-21-3: 675 floats)."""
        return storage_bytes(self.mlp.num_parameters() * float_bits(precision))

    def flops(self) -> int:
        """MLP floating-point operations per evaluation (input encoding and output transform not counted)."""
        return self.mlp.flops()


def nbrdf_from_keras(path, json_path=None, fold_phi_d: bool = True) -> NBRDF:
    """`NBRDF.from_keras`: the authors' published network `path` (.h5) + its `.json` architecture."""
    return NBRDF.from_keras(path, json_path, fold_phi_d=fold_phi_d)
