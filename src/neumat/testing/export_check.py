"""What `neumat export --check` prints: each written export (GLSL on headless OpenGL, Slang on slangpy's CPU
device) against the torch model, and at fp16 whether the model's parameters are the halves the export stores."""
from __future__ import annotations

import torch

from ..export.glsl_common import GLSL_VERSION
from ..nn import cpu_kernels
from .parity import glsl_eval, neupress_parity


def half_note(model, precision: str) -> str | None:
    """At fp16, for a model whose recipe can end on its halves (option half_finish): whether its parameters are
    the stored halves (the export computes what the model computes) or get rounded on export."""
    import dataclasses

    from ..fit.method import options_class
    from ..models.half_precision import is_half_exact

    opts = options_class(getattr(model, "name", ""))
    if precision != "fp16" or opts is None or "half_finish" not in {f.name for f in dataclasses.fields(opts)}:
        return None
    if is_half_exact(model):
        return "fp16: the model's parameters are the stored halves (a half-aware fit): the export computes what " \
               "the model computes"
    return "fp16: the parameters are rounded to the nearest half on export (the model trained in fp32 to its end; " \
           "the recipe option half_finish ends a fit on its fp16 values)"


def export_check(fmt: str, exported, model, n: int, precision: str) -> list[str]:
    """Lines comparing a written export of format `fmt` ("glsl", "slang"; others have no check) with `model` on n
    random queries: a translucent model's S_hat and sigma, else eval on footprint queries, at fp16 also against
    the halves it stores (`half_rounded`)."""
    from ..fit.footprint_queries import footprint_queries
    from ..models.half_precision import half_rounded

    if fmt not in ("glsl", "slang"):
        return []
    what = "shader" if fmt == "glsl" else "Slang module (CPU)"
    if "translucent" in getattr(model, "source_kinds", ()):
        if fmt == "glsl":
            d = neupress_parity(exported, model, n)
        else:
            from .slang_parity import neupress_slang_parity

            d = neupress_slang_parity(exported, model, n)
        where = f" on {n} random queries" if fmt == "glsl" else ""
        return [f"{what} vs torch{where}: S_hat max difference {d['translucent']:.2e} of its largest value, sigma "
                f"max relative difference {d['sigma']:.2e}"]
    q = footprint_queries(model, model)(n, torch.Generator().manual_seed(0), torch.device("cpu"))
    with torch.no_grad(), cpu_kernels.switched_off():  # the formulas the export was translated from
        ref = model.eval(q)
        half = half_rounded(model).eval(q) if precision == "fp16" else None
    if fmt == "glsl":  # with images: as images (its fastest GLSL), then through samplers (the GLSL 3.30 form)
        runs = [(glsl_eval(exported, q), f"{what} ({exported.fastest_glsl_version()})" if exported.images else what)]
        if exported.images:
            runs.append((glsl_eval(exported, q, version=GLSL_VERSION), f"{what} ({GLSL_VERSION})"))
    else:
        from .slang_parity import slang_eval

        runs = [(slang_eval(exported, q), what)]  # (output, what it ran as)
    lines = []
    for got, name in runs:
        first = f"{name} vs torch on {n} Sec. 4.2 queries" if fmt == "glsl" else f"{name} vs torch on the same queries"
        for reference, text in ((ref, first),
                                (half, f"{name} vs torch with the halves stored (half_rounded)")):
            if reference is not None:
                rel = (got - reference).abs() / reference.abs().clamp(min=1e-6)
                lines.append(f"{text}: max relative difference {float(rel.max()):.2e}, "
                             f"median {float(rel.median()):.2e}")
    return lines
