"""`neumat fit-clusters`: NeuBRDF with codebooks shared per cluster (Dou et al. 2024, Sec. 3.3) from the command
line. Clusters the sources (convolutional autoencoder + k-means,
`neumat.methods.neubrdf.shared_targets.cluster_materials`), fits one shared-neubrdf per cluster through the one trainer,
scores every member against its source, and writes OUT/cluster<c>.nmat per cluster and OUT/clusters.json (which material
went where, and how well)."""
from __future__ import annotations

import json
import math
import re
import shlex
import sys
from dataclasses import replace
from pathlib import Path

import typer

from ..core.errors import DataFormatError, InputError
from ..io.atomic import atomic_write
from .common import SEED_RANGE, _finite_or_none, device_option, parse_overrides, print_table, run_command

MODEL = "shared-neubrdf"


def register(app: typer.Typer) -> None:
    app.command("fit-clusters")(fit_clusters)


def fit_clusters(sources: list[str] = typer.Argument(..., help="BRDF sources: material files (.binary, .bsdf, "
                                                      ".h5, .nmat, ...), folders of them, .txt files listing one "
                                                      "a line, or analytic specs"),
                 k: int = typer.Option(..., "-k", "--clusters", min=1, help="number of clusters (k-means), at "
                                                                          "most the number of sources"),
                 set_: list[str] = typer.Option(None, "--set", help="key=value, as `neumat fit --set` for "
                                                "shared-neubrdf: config fields (nside=16), recipe fields "
                                                "(batch_size: queries per member per step) and options "
                                                "(cluster_steps, cluster_resolution, cluster_code_dim, ...)"),
                 steps: int = typer.Option(None, min=0, help="optimiser steps of each cluster's fit (default: "
                                                             "the recipe's)"),
                 preset: str = typer.Option(None, "--preset", help="a preset of shared-neubrdf, as `neumat fit "
                                            "--preset` (default: recommended)"),
                 recipe_alias: str = typer.Option(None, "--recipe", hidden=True, help="the old name of --preset"),
                 device: str = typer.Option(None, callback=device_option,
                                            help="torch device (default: cuda if available, else cpu)"),
                 seed: int = typer.Option(None, **SEED_RANGE, help="seed of the autoencoder, k-means, the model "
                                                                  "initialisations and the queries (default: "
                                                                  "the recipe's)"),
                 source_option: list[str] = typer.Option(None, "--source-option",
                                                         help="key=value for the source readers"),
                 eval_n: int = typer.Option(2 ** 16, "--n-configs", "--eval-n", min=0,
                                            help="random (wi, wo) configurations of each member's reflectance "
                                                 "errors against its source; 0: none (--eval-n: its old name)"),
                 quiet: bool = typer.Option(False, "--quiet", "-q", help="no training progress"),
                 out: Path = typer.Option(..., "-o", "--out", help="output folder: cluster<c>.nmat, "
                                                                   "clusters.json")) -> None:
    """Cluster the SOURCES into K groups (paper Sec. 3.3: a convolutional autoencoder on each material's
    log(1 + f) Rusinkiewicz table, k-means on its codes) and fit one shared-neubrdf (one MLP and codebook, an
    index grid per member) per cluster through the one trainer. Each fit draws --set batch_size queries per
    member per step, so every material sees as many queries as in a `neumat fit` of its own, whatever its
    cluster's size. Clusters are numbered in the order of their first source (the first source is member 0 of
    cluster 0); members keep the order of the sources. Writes OUT/cluster<c>.nmat (its member i: `neumat eval
    OUT/cluster<c>.nmat --member i`) and OUT/clusters.json: per source its cluster, member index, autoencoder
    code and reconstruction error, its reflectance errors against the source and bytes; per cluster its
    members, bytes and fit time. An earlier run's cluster<c>.nmat beyond this run's clusters are removed."""

    def go():
        from ..catalog.modelfile import load_model, save_model
        from neumat.methods.neubrdf.shared_targets import cluster_materials
        from ..fit.trainer import fit
        from .fit_many import expand_sources, source_names
        from ..fit.preset import build_fit
        from ..fit.method import typed_options
        from .fitting import chosen_preset, preset_note, resolve_device

        if out.exists() and not out.is_dir():
            raise InputError(f"-o/--out: {str(out)!r} is a file; expected a folder")
        overrides = parse_overrides(set_)
        if "num_materials" in overrides:
            raise InputError("--set num_materials: fit-clusters sets each cluster's number of materials itself")
        dev = resolve_device(device)
        name = chosen_preset(preset, recipe_alias)
        paths = expand_sources(sources)
        if k > len(paths):
            raise InputError(f"-k {k}: more clusters than materials; expected at most {len(paths)} (the number "
                             f"of sources)")
        names = source_names(paths)
        materials = [open_brdf(p, parse_overrides(source_option, "--source-option")) for p in paths]
        # checks --set and gives the recipe before the clustering (the model of this call is not used)
        _, resolved = build_fit(MODEL, name, device=dev, source=materials[:1], overrides=overrides, seed=seed)
        if not quiet:
            print(preset_note(MODEL, resolved))
        recipe = resolved.recipe
        opts = typed_options(MODEL, recipe.options)
        settings = {"resolution": opts.cluster_resolution, "code_dim": opts.cluster_code_dim,
                    "width": opts.cluster_width, "steps": opts.cluster_steps, "lr": opts.cluster_lr,
                    "seed": recipe.seed}
        print(f"clustering {len(paths)} materials into {k}: autoencoder on {settings['resolution']}^3 tables, "
              f"{settings['steps']} steps, then k-means", flush=True)
        clustering = cluster_materials(materials, k, device=dev, **settings)
        out.mkdir(parents=True, exist_ok=True)
        groups = sorted(clustering.groups, key=min)  # cluster c: the c-th in the order of their first source
        label_of = {j: c for c, group in enumerate(groups) for j in group}
        rows = {p: {"name": names[p], "cluster": label_of[j], "code": clustering.codes[j].tolist(),
                    "reconstruction_mse": float(clustering.errors[j])} for j, p in enumerate(paths)}
        clusters = []
        for label, group in enumerate(groups):
            members = [paths[j] for j in group]
            nmat = out / f"cluster{label}.nmat"
            print(f"cluster {label}: {len(members)} material(s): {', '.join(names[p] for p in members)}", flush=True)
            model, built = build_fit(MODEL, name, device=dev, source=[materials[j] for j in group],
                                     overrides=overrides, seed=seed)
            joint = replace(built.recipe, batch_size=built.recipe.batch_size * len(members))
            result = fit(model, [materials[j] for j in group], joint, steps=steps, device=dev, progress=not quiet)
            loss = result.history[-1]["loss"] if result.history else None
            if loss is not None and not math.isfinite(loss):
                raise DataFormatError(f"the fit of cluster {label} ({', '.join(members)}) ended with a non-finite "
                                      f"loss ({loss})")
            save_model(result.model.runtime(), nmat, recipe=result.recipe, source=members,
                       metrics={"final_loss": loss, "fit_seconds": result.seconds},
                       preset={"name": built.preset, "overrides": built.applied})
            shipped = load_model(nmat, device=dev)
            for i, j in enumerate(group):
                view = shipped.material(i)
                rows[paths[j]].update(member=i, nmat=nmat.name, bytes_fp16=float(view.size_bytes("fp16")),
                                      metrics=member_errors(view, materials[j], eval_n, dev))
            clusters.append({"cluster": label, "nmat": nmat.name, "members": [names[p] for p in members],
                             "sources": members, "bytes_fp16": int(shipped.size_bytes("fp16")),
                             "file_bytes": nmat.stat().st_size, "steps": result.steps,
                             "fit_seconds": result.seconds, "final_loss": loss})
        summary = {"command": "neumat fit-clusters " + shlex.join(sys.argv[2:] if "fit-clusters" in sys.argv[1:2]
                                                                  else []),
                   "k": k, "clustering": settings | {"reconstruction_mse": clustering.reconstruction_mse},
                   "recipe": {"batch_size_per_material": recipe.batch_size, "steps": clusters[0]["steps"]},
                   "materials": rows, "clusters": clusters}
        text = json.dumps(_finite_or_none(summary), indent=1, allow_nan=False)
        atomic_write(out / "clusters.json", lambda tmp: Path(tmp).write_text(text + "\n"))
        stale = sorted(p for p in out.glob("cluster*.nmat")
                       if (m := re.fullmatch(r"cluster(\d+)\.nmat", p.name)) and int(m.group(1)) >= len(clusters))
        for path in stale:  # a former run's clusters beyond this run's: clusters.json no longer lists them
            path.unlink()
        if stale:
            print(f"removed {len(stale)} model(s) of an earlier run with more clusters: "
                  f"{', '.join(p.name for p in stale)}")
        print_table(f"fit-clusters: {len(paths)} materials in {len(clusters)} clusters",
                    [{"cluster": c["cluster"], "members": ", ".join(c["members"]), "bytes_fp16": c["bytes_fp16"],
                      "bytes/material": round(c["bytes_fp16"] / len(c["members"])),
                      "mean log_err": _mean(rows[p].get("metrics", {}).get("log_err") for p in c["sources"]),
                      "fit_s": round(c["fit_seconds"], 1)} for c in clusters])
        print(f"wrote {len(clusters)} model(s) and {out / 'clusters.json'}")
    run_command(go)


def open_brdf(path: str, options: dict):
    """The Material `path` names, checked to be a plain BRDF (what the clustering tabulates and shared-neubrdf
    fits): InputError naming the source otherwise."""
    from ..catalog.open_material import open_material

    m = open_material(path, **options)
    if getattr(m, "spatially_varying", False) or getattr(m, "full_sphere", False):
        kind = "spatially varying (an SVBRDF or BTF)" if m.spatially_varying else "full-sphere (translucent)"
        raise InputError(f"source {path!r} is {kind}; fit-clusters clusters and fits plain BRDFs (MERL .binary, "
                         "RGL .bsdf, NBRDF .h5, analytic specs, BRDF models)")
    return m


def member_errors(material, source, n: int, device) -> dict[str, float]:
    """`reflectance_errors` of a fitted member against its source over n cosine-weighted queries ({} for n 0)."""
    from ..metrics.hdr import reflectance_errors

    return {} if n == 0 else {k: float(v) for k, v in reflectance_errors(material, source, n=n, seed=0,
                                                                            device=device).items()}


def _mean(values) -> float | None:
    vals = [v for v in values if v is not None]
    return sum(vals) / len(vals) if vals else None

