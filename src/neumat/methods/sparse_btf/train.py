"""Training recipe of SparseBTF (Kavoosi et al., EGSR 2023): "dictionary then coding", two solver phases of the
one trainer. `fit(SparseBTF.for_btf(btf, ...), btf)`; the source is ONE tabulated BTF (`neumat.io.btf.read_btf`).

Details (schedule, options, measurements): src/neumat/methods/sparse_btf/NOTES.md,
section `neumat.methods.sparse_btf.train`.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

import torch
from torch import nn

from neumat.core.config import bounded, config_to_dict
from neumat.core.errors import InputError
from neumat.methods.sparse_btf.btf_size import btf_table_size
from neumat.methods.sparse_btf.dictionary import BTFDictionary, code_points
from neumat.fit.phase import FitContext, Phase
from neumat.fit.recipe import Recipe
from neumat.fit.method import typed_options
from neumat.methods.sparse_btf.dictionary_train import (check_points, ensemble_iteration, has_converged, init_ensemble,
                                                        keep_count, objective)



@dataclass
class Options:
    """SparseBTF's recipe options (module docstring); also the defaults of `train_dictionary`."""

    dictionary: str | None = None
    """Path of a dictionary .nmat from `neumat fit-dictionary` to code with; None: train one on the source BTF."""
    fraction: float = bounded(1.0, gt=0, le=1)
    """Random fraction of the BTF's data points the dictionary phase trains on."""
    tol: float = bounded(1e-3, ge=0)
    """Relative objective decrease of an iteration below which a channel has converged and stops."""


RECIPE = Recipe(steps=21, batch_size=1, lr=1.0, log_every=1, checkpoint_every=1, options=config_to_dict(Options()))

#: RECIPE itself (module docstring)
CPU_RECIPE = RECIPE


def config_for_source(btf, options: dict | None = None) -> dict:
    """The model's size from the BTF (direction counts, texels) and, with option "dictionary", the fields the
    dictionary was trained with (patch, K, tau_train, log eps)."""
    out = btf_table_size(btf, "sparse-btf")
    path = typed_options("sparse-btf", options or {}).dictionary
    if path is not None:
        d = BTFDictionary.load(Path(path))
        out.update(patch=d.patch, num_dictionaries=d.num_dictionaries, tau_train=list(d.tau_train),
                   log_eps=d.log_eps)
    return out


class DictionaryState(nn.Module):
    """What the dictionary phase keeps across its steps besides the ensembles (which are model buffers):
    objective (3, iterations) per channel and iteration (NaN until run), iterations run and converged flags."""

    def __init__(self, iterations: int) -> None:
        super().__init__()
        self.register_buffer("objective", torch.full((3, iterations), float("nan"), dtype=torch.float64))
        self.register_buffer("iterations", torch.zeros(3, dtype=torch.long))
        self.register_buffer("converged", torch.zeros(3, dtype=torch.bool))


def phases(ctx: FitContext) -> list[Phase]:
    from neumat.methods.sparse_btf.model import SparseBTF

    model, btf = ctx.model, ctx.source
    if not isinstance(model, SparseBTF):
        raise InputError(f"sparse-btf recipe: expected a SparseBTF model, got {type(model).__name__}")
    if isinstance(btf, (list, tuple)):
        raise InputError("sparse-btf: the source is ONE BTF to code; train a dictionary on several BTFs with "
                         "`neumat fit-dictionary` (neumat.methods.sparse_btf.dictionary_train.train_dictionary) "
                         "and give it as "
                         "option 'dictionary'")
    model.check_source(btf)
    cfg, dev = model.cfg, ctx.device
    path = ctx.opts.dictionary
    coding = Phase("coding", 1, lambda step: {"mse": model.code(btf)})
    if path is not None:
        dictionary = BTFDictionary.load(Path(path), device=dev)
        _check_dictionary(model, dictionary, btf, path)
        if not ctx.resuming:
            with torch.no_grad():
                for c, ens in enumerate(dictionary.ensembles):
                    for n in range(4):
                        getattr(model, f"dict_{n + 1}")[c] = ens.mats[n]
        return [Phase("dictionary", 0, lambda step: {}), coding]

    warnings.warn(f"sparse-btf: no option 'dictionary' given, so the dictionary is trained on the BTF it then codes "
                  f"({getattr(btf, 'label', 'source')!r}); the result does not measure how well a dictionary "
                  "generalises to BTFs it has not seen (train one on other BTFs with `neumat fit-dictionary`)",
                  stacklevel=2)
    iterations = max(ctx.recipe.steps - 1, 0)
    tol = ctx.opts.tol
    points = _training_points(ctx, btf)
    for c in range(3):
        check_points(points[c], cfg.num_dictionaries, cfg.tau_train[c])
    state = DictionaryState(iterations)
    if not ctx.resuming:
        with torch.no_grad():
            for c in range(3):
                ens = init_ensemble(points[c], cfg.num_dictionaries, ctx.generator)
                for n in range(4):
                    getattr(model, f"dict_{n + 1}")[c] = ens.mats[n]
    codes: dict[int, object] = {}       # codes of the current ensembles: a cache, recomputed after a resume

    @torch.no_grad()
    def iterate(step: int) -> dict[str, torch.Tensor]:
        out = {}
        for c, ch in enumerate("YUV"):
            done = int(state.iterations[c])
            if not bool(state.converged[c]):
                ens, tau = model.ensemble(c), cfg.tau_train[c]
                start = codes[c] if c in codes else code_points(points[c], ens, tau)
                codes[c] = ensemble_iteration(points[c], ens, tau, start)
                state.objective[c, done] = objective(codes[c], ens.shape)
                if done > 0 and has_converged(float(state.objective[c, done - 1]), float(state.objective[c, done]),
                                              tol):
                    state.converged[c] = True
                state.iterations[c] += 1
                done += 1
            out[ch] = state.objective[c, done - 1].clone()
        return out

    return [Phase("dictionary", iterations, iterate, stateful=[state]), coding]


def _training_points(ctx: FitContext, btf) -> torch.Tensor:
    """Data points (3, N, p, p, L, V) of the source the dictionary trains on: all of them, or a random
    `fraction` drawn with a generator seeded by recipe.seed + 2 (the same on a resumed fit)."""
    cfg = ctx.model.cfg
    from neumat.methods.sparse_btf.dictionary import prepare_btf
    points = prepare_btf(btf.data.to(ctx.device), cfg.patch, cfg.log_eps, cfg.statistics)[0]
    n = points.shape[1]
    keep = keep_count(n, cfg.num_dictionaries, ctx.opts.fraction)
    if keep >= n:
        return points
    gen = torch.Generator(device=ctx.device).manual_seed(ctx.recipe.seed + 2)
    return points[:, torch.randperm(n, generator=gen, device=ctx.device)[:keep]]


def _check_dictionary(model, dictionary: BTFDictionary, btf, path) -> None:
    cfg = model.cfg
    mine = (cfg.patch, cfg.num_dictionaries, tuple(cfg.tau_train), cfg.log_eps)
    theirs = (dictionary.patch, dictionary.num_dictionaries, tuple(dictionary.tau_train), dictionary.log_eps)
    if mine != theirs:
        raise InputError(f"sparse-btf: dictionary {str(path)!r} has (patch, K, tau_train, log_eps) = {theirs} but "
                         f"the model {mine}; build the model with those fields (SparseBTF.for_btf(btf, patch=..., "
                         "num_dictionaries=..., tau_train=..., log_eps=...))")
    dictionary.check_compatible(btf.light_dirs, btf.view_dirs, f"BTF {getattr(btf, 'label', '')!r}")
