"""`neumat list`: every registered model (its paper, the kinds of source it fits, its recipe, its exports),
every kind of material source and every export format."""
from __future__ import annotations

import typer

from .common import print_json, print_table, run_command


def register(app: typer.Typer) -> None:
    app.command("list")(list_all)


def catalogue() -> dict:
    """{"models": [one object per registered model], "sources": [...], "source_kinds": {...}, "exporters": [...]}
    as `neumat list --json` prints it; a model's "recipe" is true when `neumat fit` can train it, "recipes" are
    the names its --recipe takes."""
    from ..catalog.sources import load_sources
    from ..core.errors import UnknownNameError
    from ..export.glsl_common import load_generators
    from ..export.registry import load_formats
    from ..fit.recipe import recipe_choices, recipe_for
    from ..models.base import SOURCE_KINDS
    from ..models.registry import load_all

    models = load_all()
    exportable = load_generators()
    formats = load_formats()
    rows = []
    for name in models.names():
        cls = models.get(name)
        try:
            recipe = recipe_for(name)
        except UnknownNameError:
            recipe = None
        rows.append({"name": name, "paper": cls.paper, "source_kinds": list(cls.source_kinds),
                     "recipe": recipe is not None, "recipes": recipe_choices(name) if recipe else [],
                     "steps": recipe.steps if recipe else None, "batch_size": recipe.batch_size if recipe else None,
                     "phase_split": list(recipe.phase_split) if recipe else None,
                     "exports": formats.names() if name in exportable else []})
    sources = [{"key": key, "kind": s.kind} for key, s in load_sources().items()]
    exporters = [{"name": n, "description": formats.get(n).description} for n in formats.names()]
    return {"models": rows, "sources": sources, "source_kinds": dict(SOURCE_KINDS), "exporters": exporters}


def list_all(json: bool = typer.Option(False, "--json", help="print one JSON object instead of tables")) -> None:
    """List every registered model (paper, kinds of source it fits, recipe steps x batch, export formats), every
    kind of material source and every export format."""
    def go():
        data = catalogue()
        if json:
            return print_json(data)
        print_table("models (neumat fit SOURCE --model NAME)", [
            {"model": m["name"], "fits": ", ".join(m["source_kinds"]),
             "recipe": f"{m['steps']} x {m['batch_size']}" if m["recipe"] else "none",
             "--recipe": ", ".join(m["recipes"]) or "-",
             "exports": ", ".join(m["exports"]) or "-"} for m in data["models"]])
        print_table("what each model is", [{"model": m["name"], "paper": m["paper"]} for m in data["models"]])
        print_table("material sources (file suffix, folder or spec)",
                    [{"source": s["key"], "kind": s["kind"]} for s in data["sources"]])
        print_table("kinds of training source", [{"kind": k, "what": v} for k, v in data["source_kinds"].items()])
        print_table("export formats (neumat export)", [{"format": e["name"], "writes": e["description"]}
                                                       for e in data["exporters"]])
    run_command(go)
