"""export-parity: every exported model's GLSL (llvmpipe), Slang (slangpy CPU) and Dr.Jit runtime (LLVM) evaluation
against the torch model on the same queries: relative error median / p99 / max (the exporters' tests check tolerances; this records them)."""
from __future__ import annotations

import torch

from neumat.export.registry import load_formats
from neumat.fit.method import method_for
from neumat.models.registry import load_all
from neumat.nn import cpu_kernels
from neumat.testing.drjit_parity import drjit_available, drjit_eval
from neumat.testing.parity import glsl_eval, opengl_available
from neumat.testing.slang_parity import slang_available, slang_eval

from .. import harness
from .speed import queries, runtime_model

NAME = "export-parity"
DESCRIPTION = "GLSL, Slang and Dr.Jit exports against the torch model: relative error of eval on the same queries"
BUDGET = {
    "quick": {"ours": "neubrdf at its small config (the conformance suite's: its Slang build at the default config "
                       "alone takes ~20 s), 1024 queries", "paper": "none (an engineering check)",
              "expected_wall": "about 15 s"},
    "full": {"ours": "every registered model with an export at its default config, 2^14 queries",
             "paper": "none (an engineering check)",
             "expected_wall": "about 1 min (measured: 45 s at 7fe3dbe, 68 s beside two fits at b830e6d)"},
}


def run(run: harness.Run) -> None:
    """Export, evaluate both ways, tabulate the relative errors."""
    run.protocol["error"] = "|export - torch| / (|torch| + 1e-3) per channel, over cosine-weighted queries"
    names = ["neubrdf"] if run.quick else load_all().names()
    n = 2 ** 10 if run.quick else 2 ** 14
    targets = {"glsl": (opengl_available("egl"), glsl_eval), "slang": (slang_available("cpu"), slang_eval),
               "drjit": (drjit_available(), drjit_eval)}
    rows = []
    for fmt, (available, evaluate) in targets.items():
        if not available:
            run.skip(f"{fmt} exports", "the target is not available on this machine")
            continue
        for name in names:
            model = runtime_model(name, run.seed, **(method_for(name).small if run.quick else {}))
            try:
                exported = load_formats().get(fmt).export(model)
            except Exception as e:  # noqa: BLE001  (a model without this export: recorded, not fatal)
                run.skip(f"{fmt} export of {name}", f"{type(e).__name__}: {str(e).splitlines()[0][:120]}")
                continue
            q = queries(model, n, run.seed)
            with torch.no_grad(), cpu_kernels.switched_off():  # the formulas each export translates
                want = model.eval(q)
            err = ((evaluate(exported, q) - want).abs() / (want.abs() + 1e-3)).flatten()
            spread = float(want.std())
            rows.append({"model": name, "target": fmt, "queries": n, "median": err.median(),
                         "p99": err.quantile(0.99), "max": err.max(), "torch std": spread})
            if spread <= 1e-6 * float(want.abs().max()):  # constant up to float rounding
                run.skip(f"a meaningful {fmt} parity of {name}", "its default config evaluates to a constant (its row "
                         "checks only that); the exporter's tests compare fitted or randomised models")
    run.table("parity", "Export against torch (relative error)", rows)
