"""The NBRDF networks Sztrajman et al. (2021) published: Keras 2 weights (`NAME.h5`) + architecture (`NAME.json`).

Their training script saves a `Sequential` model with `model.save_weights(h5)` and `model.to_json()`: Dense
layers (6 -> 21 relu -> 21 relu -> 3 linear) followed by one `Lambda` layer computing ``exp(x) - 1``.
`read_nbrdf_keras` returns the plain arrays; `neumat.methods.baselines.nbrdf.nbrdf_from_keras` builds the model.

HDF5 layout (Keras 2.2 `save_weights`): root attribute `layer_names`; for each layer a group with attribute
`weight_names` (``dense_1/kernel:0``, ``dense_1/bias:0``) naming datasets under that group. A kernel is stored
(in, out): a layer computes ``x @ kernel + bias``.
"""
from __future__ import annotations

import base64
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..core.errors import DataFormatError, InputError

#: Keras activation name -> neumat activation name
_ACTIVATIONS = {"relu": "relu", "linear": "linear"}


@dataclass
class KerasMLP:
    """A dense Keras network as plain arrays.

    kernels:     per Dense layer, (in, out) float32 array: the layer computes ``x @ kernel + bias``.
    biases:      per Dense layer, (out,) float32 array.
    activations: per Dense layer, "relu" or "linear".
    output:      the transform of the trailing Lambda layer: "exp_minus_one" (``exp(x) - 1``), or None.
    layer_names: Dense layer names, in order.
    keras_version: from the file.
    """

    kernels: list[np.ndarray]
    biases: list[np.ndarray]
    activations: list[str]
    output: str | None
    layer_names: list[str] = field(default_factory=list)
    keras_version: str = ""

    @property
    def dims(self) -> tuple[int, ...]:
        """(in, hidden..., out) widths, e.g. (6, 21, 21, 3)."""
        return (self.kernels[0].shape[0], *(k.shape[1] for k in self.kernels))


def _text(v) -> str:
    return v.decode("utf8") if isinstance(v, (bytes, np.bytes_)) else str(v)


def _lambda_transform(cfg: dict, where: str) -> str:
    """"exp_minus_one" when a Keras Lambda's marshalled function is ``K.exp(x) - 1``; DataFormatError otherwise.

    The function is CPython bytecode (base64); it cannot be run portably, so only its names and constants are
    checked: a call of `exp` and the constant 1, as in the authors' ``Lambda(lambda x_: K.exp(x_) - 1)``."""
    fn = cfg.get("function")
    code = fn[0] if isinstance(fn, (list, tuple)) and fn else fn
    try:
        raw = base64.b64decode(code) if isinstance(code, str) else b""
    except ValueError:
        raw = b""
    if cfg.get("function_type") == "lambda" and b"exp" in raw and b"x_" in raw:
        return "exp_minus_one"
    raise DataFormatError(f"{where}: Lambda layer is not the NBRDF output transform exp(x) - 1")


def _architecture(json_path: Path) -> tuple[list[dict], str | None, str]:
    """Dense layer configs, the trailing Lambda's transform and the Keras version from a `to_json()` file."""
    try:
        arch = json.loads(json_path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise DataFormatError(f"Keras architecture {json_path}: not readable JSON ({e})") from e
    if not isinstance(arch, dict) or arch.get("class_name") != "Sequential":
        raise DataFormatError(f"Keras architecture {json_path}: expected a Sequential model")
    cfg = arch.get("config")
    layers = cfg.get("layers") if isinstance(cfg, dict) else cfg
    if not isinstance(layers, list) or not layers:
        raise DataFormatError(f"Keras architecture {json_path}: no layers")
    dense, output = [], None
    for n, layer in enumerate(layers):
        kind, lc = layer.get("class_name"), layer.get("config", {})
        if kind == "Dense":
            if output is not None:
                raise DataFormatError(f"Keras architecture {json_path}: Dense layer after the output Lambda")
            if lc.get("activation") not in _ACTIVATIONS or not lc.get("use_bias", True):
                raise DataFormatError(f"Keras architecture {json_path}: layer {lc.get('name')!r}: expected a Dense "
                                      f"layer with bias and relu / linear activation, got {lc.get('activation')!r}")
            dense.append(lc)
        elif kind == "Lambda" and n == len(layers) - 1:
            output = _lambda_transform(lc, f"Keras architecture {json_path}")
        else:
            raise DataFormatError(f"Keras architecture {json_path}: unsupported layer {kind!r} at position {n}")
    if not dense:
        raise DataFormatError(f"Keras architecture {json_path}: no Dense layer")
    shape = dense[0].get("batch_input_shape")
    if not (isinstance(shape, list) and len(shape) == 2 and isinstance(shape[1], int)):
        raise DataFormatError(f"Keras architecture {json_path}: first layer has no batch_input_shape [None, n]")
    return dense, output, str(arch.get("keras_version", ""))


def read_nbrdf_keras(h5_path: str | Path, json_path: str | Path | None = None) -> KerasMLP:
    """Read an NBRDF network: Keras weights `h5_path` and architecture `json_path` (default: same stem, `.json`).

    Checks the JSON (a Sequential of Dense layers with relu / linear activations, optionally ending in the
    ``exp(x) - 1`` Lambda) against the HDF5 (layer names, kernel (in, out) and bias (out,) shapes chaining from
    the declared input width, finite values). InputError when a file is missing, DataFormatError when a file
    is truncated, unreadable or does not match."""
    import h5py

    h5_path = Path(h5_path)
    json_path = h5_path.with_suffix(".json") if json_path is None else Path(json_path)
    for p, what in ((h5_path, "Keras weights"), (json_path, "Keras architecture")):
        if not p.is_file():
            raise InputError(f"{what} {p}: does not exist" +
                             (" (the NBRDF .h5 needs its .json architecture beside it)" if p is json_path else ""))
    dense, output, version = _architecture(json_path)
    width = dense[0]["batch_input_shape"][1]
    kernels, biases, names = [], [], []
    where = f"Keras weights {h5_path}"
    try:
        with h5py.File(h5_path, "r") as f:
            root = f["model_weights"] if "model_weights" in f else f
            stored = [_text(n) for n in root.attrs.get("layer_names", [])]
            for lc in dense:
                name = lc.get("name")
                if name not in stored or name not in root:
                    raise DataFormatError(f"{where}: no weights for layer {name!r} (file has {stored})")
                group = root[name]
                wnames = [_text(n) for n in group.attrs.get("weight_names", [])]
                kname = next((n for n in wnames if n.split("/")[-1].startswith("kernel")), None)
                bname = next((n for n in wnames if n.split("/")[-1].startswith("bias")), None)
                if kname is None or bname is None:
                    raise DataFormatError(f"{where}: layer {name!r}: expected kernel and bias, got {wnames}")
                kernel = np.asarray(group[kname], dtype=np.float32)
                bias = np.asarray(group[bname], dtype=np.float32)
                units = lc.get("units")
                if kernel.shape != (width, units) or bias.shape != (units,):
                    raise DataFormatError(f"{where}: layer {name!r}: kernel {kernel.shape} / bias {bias.shape}, "
                                          f"expected ({width}, {units}) / ({units},) from the architecture")
                if not (np.isfinite(kernel).all() and np.isfinite(bias).all()):
                    raise DataFormatError(f"{where}: layer {name!r}: non-finite weights")
                kernels.append(kernel)
                biases.append(bias)
                names.append(name)
                width = units
            version = _text(f.attrs.get("keras_version", version))
    except DataFormatError:
        raise
    except (OSError, KeyError, ValueError, TypeError) as e:
        raise DataFormatError(f"{where}: not a readable Keras HDF5 weights file ({e})") from e
    return KerasMLP(kernels=kernels, biases=biases, activations=[_ACTIVATIONS[lc["activation"]] for lc in dense],
                    output=output, layer_names=names, keras_version=version)
