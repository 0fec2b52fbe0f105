"""`neumat export`: a fitted model in every export format it asks for (`--format`, repeatable: the formats of
`neumat.export.registry`, glsl by default), each refusing a model it cannot take before anything is written;
--precision fp16 (default) or fp32; --check compares each written shader with the torch model
(`neumat.testing.export_check`)."""
from __future__ import annotations

import dataclasses
from pathlib import Path

import typer

from .common import run_command


def register(app: typer.Typer) -> None:
    app.command("export")(export)


def export(model: Path = typer.Argument(..., help="model file (.nmat) of a model `neumat list` shows with exports"),
           out: Path = typer.Option(..., "-o", "--out", help="output folder (created)"),
           formats: list[str] = typer.Option(["glsl"], "--format", "-f",
                                             help="export format, repeatable: glsl (GLSL 3.30 source, textures, "
                                                  "manifest.json), slang (a Slang module in OUT/slang), web (a "
                                                  "self-contained WebGL 2 page, OUT/viewer.html), drjit (the "
                                                  "Dr.Jit runtime in OUT/drjit: Mitsuba's native neumat BSDF); "
                                                  "`neumat list` names them"),
           check: int = typer.Option(0, "--check", min=0,
                                     help="also run each written shader on N random queries (headless OpenGL, "
                                          "slangpy's CPU device) and print its largest relative difference from "
                                          "the torch model"),
           precision: str = typer.Option("fp16", "--precision",
                                         help="fp16 (half textures and weights, float32 arithmetic) or fp32"),
           web: bool = typer.Option(False, "--web", hidden=True, help="the same as --format glsl --format web"),
           slang: bool = typer.Option(False, "--slang", hidden=True,
                                      help="the same as --format glsl --format slang")) -> None:
    """Write MODEL in each --format (GLSL by default) to OUT."""
    def go():
        from ..catalog.modelfile import load_model
        from ..export.registry import load_formats
        from ..testing.export_check import export_check, half_note

        registry = load_formats()
        names = list(dict.fromkeys([*formats, *(["glsl", "slang"] if slang else []),
                                    *(["glsl", "web"] if web else [])]))
        chosen = {name: registry.get(name) for name in names}  # unknown names: one line with the close matches
        m = load_model(model, device="cpu")
        exports = {name: fmt.export(m, precision) for name, fmt in chosen.items()}  # refusals before any write
        for name, exported in exports.items():
            if hasattr(exported, "title"):  # a page shows the model and the file it came from
                exports[name] = dataclasses.replace(exported, title=f"{getattr(m, 'name', 'model')} ({model.name})")
        for name, fmt in chosen.items():
            _, summary = fmt.write(exports[name], out)
            print(summary)
        note = half_note(m, precision)
        if note:
            print(note)
        if check:
            for name, exported in exports.items():
                for line in export_check(name, exported, m, check, precision):
                    print(line)
    run_command(go)
