"""fp16 parity of neural-appearance on trained models (Zeltner et al. 2024, Sec. 7: train in FP32, infer in FP16):
the half-precision runtime against the fp32 model, and which stored parameters' rounding the difference comes from.

    python benchmarks/studies/neural_appearance/neural_appearance_half.py                               # 3 sets, 1500 steps of 1024, 64^2
    python benchmarks/studies/neural_appearance/neural_appearance_half.py --sources Wood092_1K --steps 300 --no-shaders   # a smoke run
    python benchmarks/studies/neural_appearance/neural_appearance_half.py --half-finish 0      # models trained in FP32 to the end (the paper)

Each source (`benchmarks/neural_appearance_images.open_source`: a texture set, "coated:SET", "smudged:SET") is fitted
with the recipe at --steps x --batch (cached in --cache as .nmat, keyed by source, steps, batch and seed). Runtimes:
"torch half_rounded" (`neumat.models.half_precision.half_rounded`: every stored value rounded to float16, float32
arithmetic; what the fp16 exports store), the fp16 GLSL export on this OpenGL (llvmpipe) and the fp16 Slang module
on slangpy's CPU device. Queries (--queries of each, seed 5): "eval" at `footprint_queries` (cosine-weighted wi,
wo, uniform uv, Eq. 9 footprints); "pdf (sampled wo)" at directions the fp32 model samples (what a path tracer asks
after sampling); "pdf (cosine wo)" at cosine-distributed wo (what MIS asks for a light sample).

--half-finish sets the recipe's half_finish (default: the recipe's 0.1; `neumat.methods.neural_appearance.train`):
the last fraction of the latents phase trains half-aware and the fit ends on a model whose parameters are what the
fp16 exports store; 0 trains in FP32 to the end. "model vs source" is the fitted fp32 model's own error, to see
what half-aware training costs: relative L1 sum |f - f_src| / sum |f_src| at the eval queries, the source's
filtered value from 64 footprint samples (seed 6).

Relative error per query: max over RGB of |x16 - x32| / max(|x32|, 1e-6) for eval, |p16 - p32| / max(p32, 1e-6) for
the pdf; the table gives its median, 99th percentile and maximum over the queries (no query is dropped; the model's
eval is exp(.) > 0 and its pdf >= 0.05 cos(wo) / pi > 0, so the floor only matters for wo within 1e-5 of the
horizon). "L1(p16, p32)": the mean relative pdf error at the fp32 model's own samples, an estimate of the L1 distance
int |p16 - p32| dwo between the two sampling densities (twice their total variation distance).

--breakdown rounds one group of stored parameters at a time (the others kept fp32), torch only: "latents" (the
pyramid), "frames" (the shading-frame decoder, its 0.1 weight scale folded in first), "brdf mlp", "sampler mlp";
eval depends on the first three, the pdf on latents and sampler.

--compensated adds "torch: compensated rounding", an experiment (not what the exports do): every stored value is
still a float16, but each decoder layer's values are rounded one input column at a time, bias first, the rounding
error of each column pushed onto the columns not yet rounded through the inverse Gram matrix of the layer's inputs
(GPTQ, Frantar et al. 2023; inputs from 2^14 other footprint queries, seed 9, with the layers above already rounded),
so that the layer's outputs move less than with independent rounding to nearest.
"""
from __future__ import annotations

import argparse
import copy
import platform
import time
from dataclasses import replace
from pathlib import Path

import torch

from .neural_appearance_images import open_source, start_run

from neumat.catalog.modelfile import load_model, save_model
from neumat.cli.common import print_table
from neumat.core.query import Query
from neumat.export.glsl import export_glsl
from neumat.export.slang import export_slang
from neumat.fit.footprint_queries import footprint_queries
from neumat.fit.method import recipe_for
from neumat.methods.neural_appearance.train import config_for_source
from neumat.fit.trainer import fit
from neumat.models.half_precision import half_rounded, is_half_exact, round_to_half
from neumat.methods.neural_appearance.model import NeuralAppearance
from neumat.testing.parity import glsl_eval, opengl_available
from neumat.testing.slang_parity import SlangKernel, slang_available, slang_eval
from neumat.warp.hemisphere import sample_cosine_hemisphere

FLOOR = 1e-6
#: --breakdown groups: parameter-name prefixes
GROUPS = {"latents": ("spatial.",), "frames": ("frame.",), "brdf mlp": ("mlp.",), "sampler mlp": ("sampler.",)}


def relative(got: torch.Tensor, ref: torch.Tensor) -> torch.Tensor:
    """Per-query relative error (N,) (module docstring)."""
    err = (got - ref).abs() / ref.abs().clamp(min=FLOOR)
    return err.max(-1).values if err.dim() == 2 else err


def trained(spec: str, data: Path, args) -> NeuralAppearance:
    """The model of `spec`, from the cache or fitted now (module docstring)."""
    path = Path(args.cache) / (f"{spec.replace(':', '-')}_{args.size}_{args.steps}x{args.batch}_s{args.seed}"
                               f"_hf{args.half_finish:g}.nmat")
    if path.exists():
        return load_model(path)
    source = open_source(spec, data, args.size, 16)
    torch.manual_seed(args.seed)
    model = NeuralAppearance(**config_for_source(source))
    t = time.perf_counter()
    recipe = recipe_for(model.name)
    recipe = replace(recipe, batch_size=args.batch, options={**recipe.options, "half_finish": args.half_finish})
    fit(model, source, recipe, steps=args.steps, progress=False)
    print(f"# {spec}: fitted in {time.perf_counter() - t:.0f} s", flush=True)
    path.parent.mkdir(parents=True, exist_ok=True)
    save_model(model.runtime(), path)
    return model.train(False)


@torch.no_grad()
def rounded_group(model: NeuralAppearance, prefixes: tuple[str, ...]) -> NeuralAppearance:
    """A copy of `model` with the parameters under `prefixes` rounded to float16 (the frame decoder's weight
    scale folded into its weights first, as `half_rounded` does), the others left in float32."""
    out = copy.deepcopy(model).train(False)
    if "frame." in prefixes and out.frame.weight_scale != 1.0:
        out.frame.decode.weight.mul_(out.frame.weight_scale)
        out.frame.weight_scale = 1.0
    for name, p in out.named_parameters():
        if name.startswith(prefixes):
            p.copy_(round_to_half(p, name))
    return out


def _layer_inputs(model, linear, run) -> torch.Tensor:
    """Inputs (N, in) of `linear` while run(model) runs, float64."""
    got = []
    hook = linear.register_forward_hook(lambda m, i, o: got.append(i[0].detach().double()))
    with torch.no_grad():
        run(model)
    hook.remove()
    return torch.cat(got)


@torch.no_grad()
def compensated(model: NeuralAppearance, calibration: Query, damp: float = 1e-4) -> NeuralAppearance:
    """`half_rounded(model)` with the BRDF and sampler decoders rounded by GPTQ, bias first (--compensated)."""
    out = half_rounded(model)
    fp32 = dict(model.named_parameters())
    for mlp in (out.mlp, out.sampler.mlp):
        for linear in mlp.linears():
            name = next(k for k, m in out.named_modules() if m is linear)
            x = _layer_inputs(out, linear, lambda m: (m.eval(calibration), m.lobes(calibration)))
            x = torch.cat([torch.ones(len(x), 1, dtype=x.dtype), x], 1)
            w = torch.cat([fp32[f"{name}.bias"].double()[:, None], fp32[f"{name}.weight"].double()], 1)
            gram = x.T @ x / len(x)
            gram += damp * gram.diag().mean() * torch.eye(len(gram), dtype=gram.dtype)
            u = torch.linalg.cholesky(torch.cholesky_inverse(torch.linalg.cholesky(gram)), upper=True)
            for i in range(w.shape[1]):
                rounded = w[:, i].half().double()
                w[:, i:] -= ((w[:, i] - rounded) / u[i, i])[:, None] * u[i, i:][None]
                w[:, i] = rounded
            linear.bias.copy_(w[:, 0].float())
            linear.weight.copy_(w[:, 1:].float())
    return out


def query_sets(model: NeuralAppearance, spec: str, data: Path, args) -> dict[str, Query]:
    """The three query sets of the module docstring."""
    g = torch.Generator().manual_seed(5)
    q = footprint_queries(open_source(spec, data, args.size, 1))(args.queries, g, "cpu")
    with torch.no_grad():
        sampled = model.sample(q, torch.rand(len(q.wi), 2, generator=g)).wo
    cosine = sample_cosine_hemisphere(torch.rand(len(q.wi), 2, generator=g))
    return {"eval": q, "pdf (sampled wo)": q.with_wo(sampled), "pdf (cosine wo)": q.with_wo(cosine)}


def runtimes(model: NeuralAppearance, shaders: bool) -> dict:
    """name -> (eval(q), pdf(q)) callables of each fp16 runtime."""
    half = half_rounded(model)
    out = {"torch half_rounded": (half.eval, half.pdf)}
    if shaders and opengl_available():
        glsl = export_glsl(model)
        out["GLSL fp16 (llvmpipe)"] = (lambda q: glsl_eval(glsl, q), lambda q: glsl_eval(glsl, q, entry="pdf")[:, 0])
    if shaders and slang_available():
        kernel = SlangKernel(export_slang(model))
        out["Slang fp16 (CPU)"] = (lambda q: slang_eval(kernel, q), lambda q: slang_eval(kernel, q, "pdf"))
    return out


def stats(err: torch.Tensor) -> str:
    """'median / 99th percentile / max' of per-query errors."""
    return f"{float(err.median()):.1e} / {float(err.quantile(0.99)):.1e} / {float(err.max()):.1e}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sources", default="Wood092_1K,Metal027_1K,smudged:Metal027_1K")
    ap.add_argument("--size", type=int, default=64)
    ap.add_argument("--steps", type=int, default=1500)
    ap.add_argument("--batch", type=int, default=1024)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--queries", type=int, default=1 << 14)
    ap.add_argument("--half-finish", type=float, default=recipe_for("neural-appearance").options["half_finish"],
                    help="the recipe's half_finish (docstring)")
    ap.add_argument("--cache", default="/tmp/neumat_half_models")
    ap.add_argument("--no-shaders", action="store_true", help="torch half_rounded only")
    ap.add_argument("--compensated", action="store_true", help="also the GPTQ-rounded model (docstring)")
    ap.add_argument("--breakdown", action="store_true", help="one parameter group rounded at a time (docstring)")
    args = ap.parse_args()
    data, commit = start_run()
    print(f"# commit {commit}, {platform.node()}, 1 thread; {args.steps} steps x {args.batch}, {args.size}^2, "
          f"half_finish {args.half_finish:g}, {args.queries} queries per set", flush=True)
    rows = []
    for spec in args.sources.split(","):
        model = trained(spec, data, args)
        sets = query_sets(model, spec, data, args)
        with torch.no_grad():
            ref = {"eval": model.eval(sets["eval"])} | {k: model.pdf(q) for k, q in sets.items() if k != "eval"}
            target = open_source(spec, data, args.size, 64, seed=6).eval(sets["eval"])
        own = f"{float((ref['eval'] - target).abs().sum() / target.abs().sum()):.4f}"
        print(f"# {spec}: half-exact {is_half_exact(model)}, model vs source (rel L1) {own}", flush=True)
        variants = runtimes(model, not args.no_shaders)
        if args.compensated:
            g = torch.Generator().manual_seed(9)
            m = compensated(model, footprint_queries(open_source(spec, data, args.size, 1))(1 << 14, g, "cpu"))
            variants["torch: compensated rounding"] = (m.eval, m.pdf)
        if args.breakdown:
            for group, prefixes in GROUPS.items():
                m = rounded_group(model, prefixes)
                variants[f"torch: {group} rounded only"] = (m.eval, m.pdf)
        for name, (ev, pdf) in variants.items():
            with torch.no_grad():
                row = {"source": spec, "runtime": name, "model vs source": own,
                       "eval rel err (median / p99 / max)": stats(relative(ev(sets["eval"]), ref["eval"]))}
                for key in ("pdf (sampled wo)", "pdf (cosine wo)"):
                    err = relative(pdf(sets[key]), ref[key])
                    row[f"{key} rel err (median / p99 / max)"] = stats(err)
                    if key == "pdf (sampled wo)":
                        row["L1(p16, p32)"] = f"{float(err.mean()):.1e}"
            rows.append(row)
            print(row, flush=True)
    print_table(f"fp16 runtimes against the fp32 model ({args.steps} steps x {args.batch}, half_finish "
                f"{args.half_finish:g})", rows, width=260)


if __name__ == "__main__":
    main()
