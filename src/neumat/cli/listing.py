"""`neumat list`: every registered model (its paper, the kinds of source it fits, its presets, its exports),
every kind of material source and every export format; `neumat list MODEL`: its presets and every settable key."""
from __future__ import annotations

import typer

from .common import print_json, print_table, run_command


def register(app: typer.Typer) -> None:
    app.command("list")(list_all)


def catalogue() -> dict:
    """{"models": [one object per registered model], "sources": [...], "source_kinds": {...}, "exporters": [...]}
    as `neumat list --json` prints it; a model's "recipe" is true when `neumat fit` can train it, "presets" are
    the names its --preset takes."""
    from ..catalog.sources import load_sources
    from ..core.errors import UnknownNameError
    from ..export.glsl import glsl_models
    from ..export.registry import load_formats
    from ..fit.preset import presets_for
    from ..fit.method import method_for, recipe_for
    from ..models.base import SOURCE_KINDS
    from ..models.registry import load_all

    models = load_all()
    exportable = glsl_models()
    formats = load_formats()
    takes = {f: set(exportable if formats.get(f).models is None else formats.get(f).models())
             for f in formats.names()}
    rows = []
    for name in models.names():
        cls = models.get(name)
        try:
            recipe = recipe_for(name)
        except UnknownNameError:
            recipe = None
        rows.append({"name": name, "paper": cls.paper, "source_kinds": list(cls.source_kinds),
                     "recipe": recipe is not None, "presets": list(presets_for(name)) if recipe else [],
                     "steps": recipe.steps if recipe else None, "batch_size": recipe.batch_size if recipe else None,
                     "phase_split": list(recipe.phase_split) if recipe else None,
                     "exports": [f for f in formats.names() if name in takes[f]],
                     "measured": method_for(name).measured if recipe else ""})
    sources = [{"key": key, "kind": s.kind} for key, s in load_sources().items()]
    exporters = [{"name": n, "description": formats.get(n).description} for n in formats.names()]
    return {"models": rows, "sources": sources, "source_kinds": dict(SOURCE_KINDS), "exporters": exporters}


def model_catalogue(model: str) -> dict:
    """{"model", "paper", "default_preset", "presets": [{name, doc, recipe, overrides, by_recipe, by_source}], "keys":
    [{key, type, default, range, doc}]} of one model, as `neumat list MODEL --json` prints it."""
    import dataclasses

    from ..core.config import field_docs, range_text, type_text
    from ..fit.preset import DEFAULT_PRESET, presets_for, settable_keys
    from ..fit.recipe import Recipe
    from ..fit.method import options_class
    from ..models.registry import model_class

    cls = model_class(model)
    presets = [{"name": n, "doc": p.doc, "recipe": p.recipe or "cpu on a CPU, paper on a GPU",
                "overrides": dict(p.overrides), "by_recipe": {k: dict(v) for k, v in p.by_recipe.items()},
                "by_source": {k: dict(v) for k, v in p.by_source.items()}}
               for n, p in presets_for(model).items()]
    docs = {"model": field_docs(cls.Config), "recipe": field_docs(Recipe),
            "option": field_docs(options_class(model)) if options_class(model) else {}}
    keys = []
    for ns, entries in settable_keys(model).items():
        for key, (tp, default, f) in entries.items():
            default = dataclasses.asdict(default) if dataclasses.is_dataclass(default) else default
            keys.append({"key": f"{ns}.{key}", "type": type_text(tp), "default": default,
                         "range": range_text(f) if f is not None else "", "doc": docs[ns].get(key, "")})
    return {"model": model, "paper": cls.paper, "default_preset": DEFAULT_PRESET, "presets": presets, "keys": keys}


def list_all(model: str = typer.Argument(None, help="a registered model: list its presets and every key --set "
                                                     "takes"),
             json: bool = typer.Option(False, "--json", help="print one JSON object instead of tables")) -> None:
    """List every registered model (paper, kinds of source it fits, recipe steps x batch, presets, export
    formats), every kind of material source and every export format; with MODEL, that model's presets and every
    key `neumat fit --set` takes, with its type, default and what it does."""
    def go():
        from rich.markup import escape  # a doc's [lo, hi] is text, not markup

        if model is not None:
            data = model_catalogue(model)
            if json:
                return print_json(data)
            print_table(f"{model}: presets (neumat fit --preset NAME; default {data['default_preset']})", [
                {"preset": p["name"], "recipe": p["recipe"],
                 "sets": "; ".join([", ".join(f"{k}={v}" for k, v in p["overrides"].items())]
                                   + [f"with recipe {name}: " + ", ".join(f"{k}={v}" for k, v in o.items())
                                      for name, o in p["by_recipe"].items()]
                                   + [f"on {kind}: " + ", ".join(f"{k}={v}" for k, v in o.items())
                                      for kind, o in p["by_source"].items()]).strip("; ") or "-",
                 "what": p["doc"]} for p in data["presets"]], width=200)
            print_table(f"{model}: keys (neumat fit --set KEY=VALUE; a bare KEY where only one namespace has it)", [
                {"key": k["key"], "type": f"{k['type']} {'in ' if k['range'][:1] in ('[', '(') else ''}{k['range']}"
                 .strip(), "default": k["default"], "what": escape(k["doc"])} for k in data["keys"]], width=200)
            return None
        data = catalogue()
        if json:
            return print_json(data)
        print_table("models (neumat fit SOURCE --model NAME)", [
            {"model": m["name"], "fits": ", ".join(m["source_kinds"]),
             "recipe": f"{m['steps']} x {m['batch_size']}" if m["recipe"] else "none",
             "--preset": ", ".join(m["presets"]) or "-",
             "exports": ", ".join(m["exports"]) or "-"} for m in data["models"]])
        print_table("what each model is", [{"model": m["name"], "paper": m["paper"],
                                            "measured here (when to choose it)": m["measured"] or "-"}
                                           for m in data["models"]])
        print_table("material sources (file suffix, folder or spec)",
                    [{"source": s["key"], "kind": s["kind"]} for s in data["sources"]])
        print_table("kinds of training source", [{"kind": k, "what": v} for k, v in data["source_kinds"].items()])
        print_table("export formats (neumat export)", [{"format": e["name"], "writes": e["description"]}
                                                       for e in data["exporters"]])
    run_command(go)
