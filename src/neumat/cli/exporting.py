"""`neumat export`: a fitted model as GLSL source plus textures (`neumat.export.glsl`), and with --slang also as
a Slang module (`neumat.export.slang`: every model `export_glsl` takes but ggx-mipmap-like analytic ones) in
OUT/slang; --precision fp16 (default: half textures and weights, `neumat.export.half_precision`) or fp32. The
summary gives the texture and weight bytes at both precisions; --check compares with the torch model and, at
fp16, with `half_rounded(model)` (the halves it stores, float32 arithmetic)."""
from __future__ import annotations

from pathlib import Path

import typer

from .common import run_command


def register(app: typer.Typer) -> None:
    app.command("export")(export)


def export(model: Path = typer.Argument(..., help="model file (.nmat) of a multi-scale, neumip-family "
                                        "(neumip, neumip-frame, neural-appearance), neubrdf, sparse-btf or neupress model"),
           out: Path = typer.Option(..., "-o", "--out", help="output folder (created)"),
           check: int = typer.Option(0, "--check", min=0,
                                     help="also run the shader on N random queries (headless OpenGL) and print "
                                          "its largest relative difference from the torch model"),
           web: bool = typer.Option(False, "--web", help="also write OUT/viewer.html: a self-contained WebGL 2 "
                                                         "page showing the material on a sphere or a plane"),
           precision: str = typer.Option("fp16", "--precision",
                                         help="fp16 (half textures and weights, float32 arithmetic) or fp32"),
           slang: bool = typer.Option(False, "--slang", help="also write a Slang module (neumat.slang, its buffers, "
                                                             "manifest.json) to OUT/slang (the models GLSL "
                                                             "export takes); --check checks it "
                                                             "too, on slangpy's CPU device")) -> None:
    """Write MODEL as GLSL 3.30 (neumat.glsl), its textures (raw float16 or float32) and manifest.json to OUT."""
    def go():
        import torch

        from ..catalog.modelfile import load_model
        from ..export.registry import load_formats

        formats = load_formats()
        m = load_model(model, device="cpu")
        if slang:
            slang_export = formats.get("slang").export(m, precision)  # refuses other models before anything is written
        exported = formats.get("glsl").export(m, precision)  # refuses unknown models and precisions
        folder = exported.write(out)
        print(f"wrote {folder / 'neumat.glsl'} ({len(exported.source)} characters) and "
              f"{len(exported.textures)} textures to {folder}")
        sizes = {p: exported.storage_bytes(p) for p in ("fp16", "fp32")}
        print("stored bytes: " + "; ".join(f"{p} {b['textures']} textures + {b['weights']} weights = {b['total']}"
                                          for p, b in sizes.items())
              + f" (fp16 / fp32 = {sizes['fp16']['total'] / sizes['fp32']['total']:.3f}); written: {precision}"
              + (f", float32 at both: {', '.join(exported.exact)}" if exported.exact else ""))
        if precision == "fp16" and getattr(m, "name", None) == "neural-appearance":
            from ..models.half_precision import is_half_exact

            print("fp16: the model's parameters are the stored halves (a half-aware fit): the export computes what "
                  "the model computes" if is_half_exact(m) else "fp16: the parameters are rounded to the nearest "
                  "half on export (the model trained in fp32 to its end; the recipe option half_finish ends a fit on "
                  "its fp16 values)")
        if slang:
            slang_folder = slang_export.write(folder / "slang")
            print(f"wrote {slang_folder / 'neumat.slang'} ({len(slang_export.source)} characters), "
                  f"{len(slang_export.buffers)} buffer(s) and manifest.json to {slang_folder}")
        if web:
            page = formats.get("web").export(exported, folder / "viewer.html",
                                             title=f"{getattr(m, 'name', 'model')} ({model.name})")
            print(f"wrote {page} ({page.stat().st_size / 1e6:.2f} MB): open it in a browser with WebGL 2")
        if check and getattr(m, "name", None) == "neupress":
            from ..testing.parity import neupress_parity

            d = neupress_parity(exported, m, check)
            print(f"shader vs torch on {check} random queries: S_hat max difference {d['translucent']:.2e} of its "
                  f"largest value, sigma max relative difference {d['sigma']:.2e}")
            if slang:
                from ..testing.slang_parity import neupress_slang_parity

                d = neupress_slang_parity(slang_export, m, check)
                print(f"Slang module (CPU) vs torch: S_hat max difference {d['translucent']:.2e} of its largest "
                      f"value, sigma max relative difference {d['sigma']:.2e}")
        elif check:
            from ..fit.footprint_queries import footprint_queries
            from ..testing.parity import glsl_eval

            from ..models.half_precision import half_rounded

            q = footprint_queries(m, m)(check, torch.Generator().manual_seed(0), torch.device("cpu"))
            with torch.no_grad():
                ref = m.eval(q)
                half = half_rounded(m).eval(q) if precision == "fp16" else None

            def report(got: torch.Tensor, first: str, then: str) -> None:
                for reference, text in ((ref, first), (half, then)):
                    if reference is not None:
                        rel = (got - reference).abs() / reference.abs().clamp(min=1e-6)
                        print(f"{text}: max relative difference {float(rel.max()):.2e}, "
                              f"median {float(rel.median()):.2e}")

            report(glsl_eval(exported, q), f"shader vs torch on {check} Sec. 4.2 queries",
                   "shader vs torch with the halves stored (half_rounded)")
            if slang:
                from ..testing.slang_parity import slang_eval

                report(slang_eval(slang_export, q), "Slang module (CPU) vs torch on the same queries",
                       "Slang module (CPU) vs torch with the halves stored (half_rounded)")
    run_command(go)
