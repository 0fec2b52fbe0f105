"""`neumat translucent trace | fit | render`: NeuPreSS on a path-traced translucent object (Mitsuba 3)."""
from __future__ import annotations

import math
from pathlib import Path

import typer

from .common import IMAGE_OUT, SEED_RANGE, device_option, output_option, print_table, run_command

app = typer.Typer(help="Translucent objects (NeuPreSS): trace observations with Mitsuba 3, fit, render.",
                  no_args_is_help=True)


def register(main: typer.Typer) -> None:
    """Add the `translucent` sub-app to the main app."""
    main.add_typer(app, name="translucent")


#: --scene values that name a whole preset object (TranslucentConfig), not only its outer shape
SCENE_PRESETS = ("paperweight",)


def object_shape(scene: str) -> str:
    """TranslucentConfig.shape of a --scene value: 'sphere', 'cube', or the path of `mesh:PATH`."""
    if scene in ("sphere", "cube"):
        return scene
    if scene.startswith("mesh:") and scene[5:]:
        return scene[5:]
    from ..core.errors import InputError
    raise InputError(f"--scene: expected 'sphere', 'cube', mesh:PATH (a closed PLY mesh) or a preset "
                     f"({', '.join(SCENE_PRESETS)}), got {scene!r}")


def object_config(scene: str, inner: list | None, given: dict):
    """The TranslucentConfig of `trace`'s options: a preset's (`--scene paperweight`) or the defaults, with the
    options given (not None) replacing its fields and a given --inner replacing its inner shapes."""
    import dataclasses

    from ..reflectance.translucent import TranslucentConfig, paperweight_config
    given = {k: v for k, v in given.items() if v is not None}
    if scene == "paperweight":
        return dataclasses.replace(paperweight_config(), **given, **({} if inner is None else {"inner": inner}))
    return TranslucentConfig(shape=object_shape(scene), inner=inner or [], **given)


def environment_map(light: str) -> str:
    """'sky' or the map's path, from a --light value env:sky / env:PATH."""
    if light.startswith("env:") and light[4:]:
        return light[4:]
    from ..core.errors import InputError
    raise InputError(f"--light: translucent renders take an environment, env:sky or env:PATH (.hdr / .exr), "
                     f"got {light!r}")


@app.command()
def trace(out: Path = typer.Option(..., "-o", "--out", callback=output_option(".npz"),
                               help="observations file to write (.npz)"),
          scene: str = typer.Option("sphere", help="the object: 'sphere', 'cube', mesh:PATH (a closed PLY triangle "
                                                   "mesh), or the preset 'paperweight' (a weakly scattering cube "
                                                   "around a marble bunny, docs/neupress.md; the other options "
                                                   "change its fields)"),
          media: str = typer.Option(None, help="the two Jensen et al. media the noise mixes, A,B (default: "
                                               "TranslucentConfig's, as every unset object option)"),
          size_mm: float = typer.Option(None, help="millimetres across the bounding-box diagonal (smaller: more "
                                                    "translucent)"),
          roughness: float = typer.Option(None, help="GGX alpha of the dielectric surface"),
          images: int = typer.Option(8000, min=1, help="views, each with its own light direction (the default: "
                                                       "with NeuPreSS's default fit, object-pixel FLIP 0.098 / 0.112 "
                                                       "on the bunny and 0.094 on the kitten against 0.112-0.114 and "
                                                       "0.113 at 4000 views; 47-60 CPU min there on the bunny)"),
          resolution: int = typer.Option(None, min=1, help="rays per side of each view (default: "
                                                           "collect_observations')"),
          spp: int = typer.Option(256, min=1, help="paths per ray (the default: the best image per CPU second "
                                                   "measured: "
                                                   "benchmarks/studies/neupress/results/neupress_budget.md)"),
          seed: int = typer.Option(0, **SEED_RANGE),
          max_depth: int = typer.Option(None, min=2, help="longest path (default: TranslucentConfig's, the paper's)"),
          inner: str = typer.Option(None, help="shapes inside the volume: a .json file or inline JSON, a list of "
                                               "InnerShape fields, e.g. '[{\"medium\": \"skin1\", \"scale\": 0.4}]' "
                                               "(docs/neupress.md)"),
          roughness_texture: Path = typer.Option(None, help="image whose first channel maps to GGX alpha in "
                                                            "--roughness-range (latitude-longitude projection)"),
          roughness_range: str = typer.Option(None, help="alpha at roughness-texture values 0 and 1, LO,HI"),
          albedo_texture: Path = typer.Option(None, help="RGB image multiplying the medium's albedo "
                                                         "(latitude-longitude projection from the box centre)"),
          sampler: str = typer.Option(None, help="Mitsuba sampler of each ray's --spp paths: independent, or "
                                                 "orthogonal (--spp the square of a prime: 25, 49, 121; about half "
                                                 "the variance, benchmarks/studies/neupress/results/"
                                                 "neupress_variance.md)"),
          noise_check: int = typer.Option(2048, min=0, help="observations traced twice more to estimate the data's "
                                                           "Monte Carlo noise (0: skip)"),
          checkpoint: Path = typer.Option(None, help="file written every two minutes of tracing with the views done "
                                                     "so far (removed at the end)"),
          resume: bool = typer.Option(False, "--resume", help="continue the trace in --checkpoint if it exists (with "
                                                              "the same options: the file an uninterrupted trace "
                                                              "writes)"),
          threads: int = typer.Option(None, min=1, help="Mitsuba's (Dr.Jit's) CPU threads (default: all cores); "
                                                        "1 traces the same file bit for bit every run (with more, a "
                                                        "mesh's paths vary run to run)"),
          quiet: bool = typer.Option(False, "--quiet", "-q", help="no progress output")) -> None:
    """Path-trace training observations of S_hat under random directional lights (NeuPreSS Sec. 4.2)."""
    def go():
        from ..core.config import config_to_dict
        from ..core.errors import InputError
        from ..core.mitsuba import mitsuba_threads
        from ..fit.translucent_observations import collect_observations
        from ..reflectance.translucent import TranslucentObject

        _check_suffix(out, ".npz", "trace OUT")
        if resume and checkpoint is None:
            raise InputError("--resume needs --checkpoint (the file a cut-off trace left)")
        given = {"media": None if media is None else tuple(m.strip() for m in media.split(",")),
                 "size_mm": size_mm, "roughness": roughness, "max_depth": max_depth,
                 "roughness_texture": None if roughness_texture is None else str(roughness_texture),
                 "roughness_range": None if roughness_range is None else _pair(roughness_range, "--roughness-range"),
                 "albedo_texture": None if albedo_texture is None else str(albedo_texture), "sampler": sampler}
        cfg = object_config(scene, None if inner is None else _inner_shapes(inner), given)
        sizes = {} if resolution is None else {"resolution": resolution}
        with mitsuba_threads(threads):  # the scene built (its BVH) and traced on these threads
            obj = TranslucentObject(cfg, spp=spp, seed=seed)
            obs = collect_observations(obj, images, seed=seed, progress=not quiet, checkpoint=checkpoint,
                                       resume=resume, **sizes)
            cpu = obj.trace_cpu_seconds  # the observations' (the noise check's traces come after)
            source = {"object": config_to_dict(cfg), "spp": spp, "seed": seed,
                      "bbox": [obj.bbox_min.tolist(), obj.bbox_max.tolist()],
                      **({} if math.isnan(cpu) else {"trace_cpu_seconds": round(cpu, 1)})}
            noise = observation_noise(obj, obs, noise_check, seed) if noise_check else None
        if noise is not None:
            source["noise"] = noise
            share = ("" if noise["relative"] is None else
                     f", {noise['relative']:.3g} +- {noise['relative_se']:.2g} of the values' variance (the least "
                     "held-out MSE / variance a fit can show)")
            print(f"noise floor: an observation's Monte Carlo variance at {spp} spp is {noise['variance']:.3g}{share}; "
                  f"{noise['observations']} observations traced twice")
        obs.save(out, source=source)
        spent = ("CPU time unknown: resumed from a checkpoint that did not record it" if math.isnan(cpu) else
                 f"traced in {cpu / 60:.1f} CPU min")
        print(f"wrote {out}: {len(obs)} observations x {spp} paths ({obj.describe()}); {spent}")
    run_command(go)


def observation_noise(obj, obs, count: int, seed: int) -> dict:
    """The Monte Carlo noise of traced observations: up to `count` of them, from 32 views spread over the data,
    traced twice more (`TranslucentObject.noise_variance`); their mean variance, absolute and relative to the
    variance of all observed values (what `fit` reports its held-out MSE against), with the standard error of the
    relative value (the estimator is heavy-tailed: few observations underestimate it)."""
    import torch

    from ..core.query import Query

    starts = torch.cat([torch.tensor([0]), (obs.wi[1:] != obs.wi[:-1]).any(-1).nonzero().squeeze(1) + 1,
                        torch.tensor([len(obs)])])  # views: runs of one light direction
    views = torch.linspace(0, len(starts) - 2, min(32, len(starts) - 1)).round().long().unique()
    gen = torch.Generator().manual_seed(int(seed))
    per_view = max(1, count // len(views))
    idx = torch.cat([starts[v] + torch.randperm(int(starts[v + 1] - starts[v]), generator=gen)[:per_view]
                     for v in views.tolist()])
    variance = obj.noise_variance(Query(wi=obs.wi[idx], wo=obs.wo[idx], x=obs.x[idx]))
    values = float(obs.value.double().var())
    noise, se = float(variance.mean()), float(variance.mean(-1).std() / idx.numel() ** 0.5)
    return {"observations": int(idx.numel()), "variance": noise,
            "relative": noise / values if values > 0 else None, "relative_se": se / values if values > 0 else None}


def _inner_shapes(text: str | None) -> list:
    """--inner: None, the path of a .json file or inline JSON, holding a list of InnerShape field dicts."""
    import json

    from ..core.errors import InputError
    if text is None:
        return []
    source = Path(text).read_text() if text.strip().endswith(".json") and Path(text).is_file() else text
    try:
        shapes = json.loads(source)
    except ValueError as e:
        raise InputError(f"--inner: expected a .json file or inline JSON (a list of inner shapes), got {text!r}: "
                         f"{e}") from None
    if not isinstance(shapes, list) or not all(isinstance(s, dict) for s in shapes):
        raise InputError(f"--inner: expected a list of objects (InnerShape fields), got {shapes!r}")
    return shapes


def _orbit(obj, resolution: int, azimuth: float | None, elevation: float | None):
    """`orbit_camera` with its own defaults for the angles not given."""
    from ..render.translucent import orbit_camera
    angles = {k: v for k, v in (("azimuth", azimuth), ("elevation", elevation)) if v is not None}
    return orbit_camera(obj, resolution, **angles)


def _pair(text: str, what: str) -> tuple[float, float]:
    from ..core.errors import InputError
    try:
        lo, hi = (float(v) for v in text.split(","))
    except ValueError:
        raise InputError(f"{what}: expected two numbers LO,HI, got {text!r}") from None
    return lo, hi


@app.command(hidden=True)
def fit(observations: Path = typer.Argument(..., help="observations file from `neumat translucent trace`"),
        out: Path = typer.Option(..., "-o", "--out", callback=output_option(".nmat"),
                                 help="model file to write (.nmat)"),
        set_: list[str] = typer.Option(None, "--set", help="key=value, as `neumat fit --set`"),
        steps: int = typer.Option(None, min=0, help="optimiser steps (default: the preset's)"),
        validation: float = typer.Option(None, help="the same as --set validation_fraction=X"),
        device: str = typer.Option(None, callback=device_option,
                                   help="torch device (default: cuda if available, else cpu)"),
        seed: int = typer.Option(None, help="seed of the recipe (default: the recipe's)", **SEED_RANGE),
        checkpoint: Path = typer.Option(None, help="checkpoint file, written during the fit"),
        resume: bool = typer.Option(False, "--resume", help="continue from --checkpoint if it exists"),
        quiet: bool = typer.Option(False, "--quiet", "-q", help="no progress bar")) -> None:
    """The old name of `neumat fit OBSERVATIONS.npz --model neupress` (the same fit, bounds and report)."""
    def go():
        from ..fit.preset import DEFAULT_PRESET
        from .common import parse_overrides
        from .fitting import run_fit

        overrides = parse_overrides(set_)
        if validation is not None:
            overrides["option.validation_fraction"] = validation
        run_fit("neupress", [str(observations)], DEFAULT_PRESET, overrides, out, steps=steps, device=device,
                seed=seed, checkpoint=checkpoint, resume=resume, quiet=quiet)
    run_command(go)


@app.command()
def render(model: Path = typer.Argument(..., help="NeuPreSS model file (.nmat)"),
           observations: Path = typer.Argument(..., help="its observations file (names the object it shows)"),
           out: Path = typer.Option(..., "-o", "--out", callback=output_option(*IMAGE_OUT),
                                    help="image (.png, .exr, .hdr); with --reference-spp a "
                                                            "comparison picture (.png)"),
           light: str = typer.Option("env:sky", help="the environment: env:sky or env:PATH (equirectangular .hdr / "
                                                     ".exr), as `neumat render --light`"),
           env_width: int = typer.Option(128, help="box-filter the map to this width first"),
           resolution: int = typer.Option(64, min=8, help="image width and height"),
           spp: int = typer.Option(64, min=1, help="samples per pixel"),
           strategy: str = typer.Option("mis", help="light (environment importance sampling) | model (the "
                                                    "learned Gaussian lobe) | mis (their mixture, balance "
                                                    "heuristic)"),
           appearance: str = typer.Option("full", help="full (surface reflection + subsurface, over the "
                                                       "environment) | subsurface (the learned term on black)"),
           reference_spp: int = typer.Option(0, min=0, help="also path-trace the reference of the same appearance "
                                                           "at this many spp (twice: the second, another seed, "
                                                           "gives the noise floor) and compare"),
           azimuth: float = typer.Option(None, help="camera azimuth in degrees (default: orbit_camera's)"),
           elevation: float = typer.Option(None, help="camera elevation in degrees (default: orbit_camera's)"),
           seed: int = typer.Option(0, **SEED_RANGE),
           device: str = typer.Option(None, "--device", callback=device_option,
                                      help="torch device the model is evaluated on (default: cuda if available, "
                                           "else cpu)")) -> None:
    """Render MODEL on the geometry of its object under an environment map (Eq. 5)."""
    def go():
        import time

        from ..core.errors import InputError
        from ..io.images import write_image, write_image_ldr
        from ..render.translucent import (APPEARANCES, STRATEGIES, image_scores, object_mask, render_translucent,
                                          render_translucent_reference)
        from ..viz.compare import compare_image

        environment_map(light)  # a bad --light is reported before anything is loaded
        for option, value, known in (("--strategy", strategy, STRATEGIES), ("--appearance", appearance, APPEARANCES)):
            if value not in known:
                raise InputError(f"{option}: expected one of {'|'.join(known)}, got {value!r}")
        if reference_spp and out.suffix.lower() != ".png":
            raise InputError(f"--out {out}: the comparison picture of --reference-spp is a .png")
        m = _neupress(model, device)
        obj = _translucent_object(observations, seed)  # loads Mitsuba: after every check of the arguments
        env = _environment(light, env_width)
        camera = _orbit(obj, resolution, azimuth, elevation)
        t = time.perf_counter()
        img = render_translucent(m, obj, env, camera, resolution, spp=spp, strategy=strategy, seed=seed,
                                 appearance=appearance)
        seconds = time.perf_counter() - t
        if not reference_spp:
            write_image(out, img, tonemap="aces")
            print(f"wrote {out} ({seconds:.1f} s)")
            return
        t = time.perf_counter()
        references = [render_translucent_reference(obj, env, camera, resolution, spp=reference_spp, seed=seed + k,
                                                   appearance=appearance) for k in (1, 2)]
        ref_seconds = (time.perf_counter() - t) / 2
        reference = references[0]
        mask = object_mask(obj, camera, resolution).numpy()
        name = f"NeuPreSS, {appearance}, {strategy}, {spp} spp"
        floor = f"reference, another seed ({reference_spp} spp)"
        scores = {name: image_scores(reference, img, mask), floor: image_scores(reference, references[1], mask)}
        shown = {k: {"flip": v["flip"], "object_flip": v["object_flip"], "mse": v["mse"]} for k, v in scores.items()}
        write_image_ldr(out, compare_image(reference, {name: img, floor: references[1]}, shown, tonemap="aces"))
        print_table(f"wrote {out}: against a {reference_spp}-spp path-traced reference ({ref_seconds:.0f} s); the "
                    "second row is the reference's own noise floor", [
                        {"method": k, "seconds": seconds if k == name else ref_seconds, "MSE": v["mse"],
                         "FLIP": v["flip"], "FLIP, object": v["object_flip"], "SSIM": v["ssim"]}
                        for k, v in scores.items()])
    run_command(go)


def _check_suffix(path: Path, suffix: str, what: str) -> None:
    from ..core.errors import InputError
    if path.suffix.lower() != suffix:
        raise InputError(f"{what}: expected a {suffix} file, got {str(path)!r}")


@app.command("prt")
def prt(model: Path = typer.Argument(..., help="NeuPreSS model file (.nmat)"),
        observations: Path = typer.Argument(..., help="its observations file (names the object and so the mesh)"),
        out: Path = typer.Option(..., "-o", "--out", callback=output_option(".prt"),
                                 help="SH PRT table to write (.prt)"),
        view_bins: str = typer.Option(None, help="view bins per vertex, THETAxPHI (default: "
                                                 "neumat.methods.neupress.prt.FAST_VIEW_BINS, 8x16; the paper 16x64)"),
        light_samples: int = typer.Option(None, min=1, help="light directions of the Gauss rule per view bin "
                                                            "(default: FAST_LIGHT_SAMPLES, 32; the paper 1024)"),
        precision: str = typer.Option(None, help="network arithmetic, bf16 or fp32 (default: FAST_PRECISION, "
                                                 "bf16: 2-3x faster, a_lm within ~1% of fp32)"),
        degree: int = typer.Option(2, min=0, help="SH degree in the light direction (the paper: 2)"),
        subdivisions: int = typer.Option(4, min=0, max=7, help="for the analytic sphere: icosphere subdivisions "
                                                               "(10 4^s + 2 vertices)"),
        batch_size: int = typer.Option(16384, min=1, help="network evaluations per batch"),
        device: str = typer.Option(None, "--device", callback=device_option,
                                   help="torch device the model is evaluated on (default: cuda if available, "
                                        "else cpu)"),
        quiet: bool = typer.Option(False, "--quiet", "-q", help="no progress bar")) -> None:
    """Precompute the SH PRT table of MODEL (NeuPreSS Sec. 4.3) at every vertex of its object's mesh."""
    def go():
        import time

        from neumat.methods.neupress.prt import (FAST_LIGHT_SAMPLES, FAST_PRECISION, FAST_VIEW_BINS, SHPRT, PRTConfig,
                                           check_config)
        from ..render.mesh import object_mesh, vertex_normals

        _check_suffix(out, ".prt", "prt --out")
        m = _neupress(model, device)
        vt, vp = _view_bins(view_bins) if view_bins else FAST_VIEW_BINS
        cfg = check_config(PRTConfig(degree=degree, view_theta=vt, view_phi=vp, batch_size=batch_size,
                                     light_samples=light_samples or FAST_LIGHT_SAMPLES,
                                     precision=precision or FAST_PRECISION))
        obj = _translucent_object(observations)  # loads Mitsuba: after every check of the arguments
        vertices, faces = object_mesh(obj, subdivisions)
        normals = vertex_normals(vertices, faces)
        t = time.perf_counter()
        table = SHPRT.from_material(m, vertices.float(), normals.float(), cfg, progress=not quiet, device=device,
                                    faces=faces)
        seconds = time.perf_counter() - t
        table.to("cpu").save(out)
        size = table.size_bytes("fp16")
        print_table(f"wrote {out}", [{"vertices": table.num_vertices, "view bins": f"{vt}x{vp}",
                                      "light directions": _light_count(cfg), "precision": cfg.precision,
                                      "seconds": round(seconds, 1),
                                      "fp16 bytes": size, "bytes per vertex": size // table.num_vertices}])
    run_command(go)


@app.command("prt-render")
def prt_render(table: Path = typer.Argument(..., help="SH PRT table from `neumat translucent prt` (.prt)"),
               observations: Path = typer.Argument(..., help="the observations file of its object (for the camera "
                                                             "and the reference)"),
               out: Path = typer.Option(..., "-o", "--out", callback=output_option(*IMAGE_OUT),
                                        help="image (.png, .exr, .hdr); with --model or --reference-spp a "
                                             "comparison picture (.png)"),
               light: str = typer.Option("env:sky", help="the environment: env:sky or env:PATH (.hdr / .exr)"),
               env_width: int = typer.Option(128, help="box-filter the map to this width first"),
               resolution: int = typer.Option(64, min=8, help="image width and height"),
               spp: int = typer.Option(4, min=1, help="samples per pixel of the table's image (anti-aliasing)"),
               model: Path = typer.Option(None, help="also render this NeuPreSS model (Eq. 5, `translucent render`) "
                                                     "and compare"),
               model_spp: int = typer.Option(64, min=1, help="samples per pixel of the model's image"),
               reference_spp: int = typer.Option(0, min=0, help="also path-trace the reference at this many spp "
                                                               "and compare"),
               azimuth: float = typer.Option(None, help="camera azimuth in degrees (default: orbit_camera's)"),
               elevation: float = typer.Option(None, help="camera elevation in degrees (default: orbit_camera's)"),
               seed: int = typer.Option(0, **SEED_RANGE),
               device: str = typer.Option(None, "--device", callback=device_option,
                                          help="torch device of the table and the model (default: cuda if available, "
                                               "else cpu)")) -> None:
    """Render an SH PRT table (Eq. 11) under an environment map, optionally against the network and the
    path-traced reference (subsurface light only, as `translucent render`)."""
    def go():
        import time

        from ..core.errors import InputError
        from ..io.images import write_image, write_image_ldr
        from ..metrics.image import image_metrics
        from neumat.methods.neupress.prt import SHPRT
        from ..render.translucent import render_translucent, render_translucent_reference
        from ..render.translucent_prt import render_prt
        from ..viz.compare import compare_image

        _check_suffix(table, ".prt", "prt-render TABLE")
        if (model is not None or reference_spp) and out.suffix.lower() != ".png":
            raise InputError(f"--out {out}: the comparison picture of --model / --reference-spp is a .png")
        environment_map(light)
        prt_table = SHPRT.load(table, device=device)
        net = _neupress(model, device) if model is not None else None
        obj = _translucent_object(observations, seed)  # loads Mitsuba: after every check of the arguments
        env = _environment(light, env_width)
        camera = _orbit(obj, resolution, azimuth, elevation)
        t = time.perf_counter()
        images = {"SH PRT": render_prt(prt_table, env, camera, resolution, spp=spp, seed=seed)}
        seconds = {"SH PRT": time.perf_counter() - t}
        if net is None and not reference_spp:
            write_image(out, images["SH PRT"], tonemap="aces")
            print(f"wrote {out} ({seconds['SH PRT']:.1f} s)")
            return
        if net is not None:
            t = time.perf_counter()
            images["network"] = render_translucent(net, obj, env, camera, resolution, spp=model_spp, seed=seed)
            seconds["network"] = time.perf_counter() - t
        if reference_spp:
            t = time.perf_counter()
            images["reference"] = render_translucent_reference(obj, env, camera, resolution, spp=reference_spp,
                                                               seed=seed + 1)
            seconds["reference"] = time.perf_counter() - t
        rows, panels, scores = [], {}, {}
        pairs = [("SH PRT", "network"), ("SH PRT", "reference"), ("network", "reference")]
        for test, ref in pairs:
            if test in images and ref in images:
                s = image_metrics(images[ref].numpy(), images[test].numpy(), tonemap="aces")
                s["mse"] = float(((images[test] - images[ref]) ** 2).mean())
                name = f"{test} vs {ref}"
                rows.append({"image": test, "against": ref, "seconds": round(seconds[test], 2), "MSE": s["mse"],
                             "FLIP": s["flip"], "SSIM": s["ssim"]})
                if ref == ("reference" if reference_spp else "network"):
                    panels[name], scores[name] = images[test], s
        base = images["reference" if reference_spp else "network"]
        write_image_ldr(out, compare_image(base, panels, scores, tonemap="aces"))
        print_table(f"wrote {out}", rows)
    run_command(go)


def _neupress(path: Path, device: str):
    """The NeuPreSS model in `path` on `device` (InputError for another kind of model)."""
    from ..catalog.modelfile import load_model
    from ..core.errors import InputError
    from neumat.methods.neupress.model import NeuPreSS

    _check_suffix(path, ".nmat", "MODEL")
    m = load_model(path, device=device)
    if not isinstance(m, NeuPreSS):
        raise InputError(f"{path}: expected a NeuPreSS model, got {type(m).__name__}")
    return m


def _translucent_object(observations: Path, seed: int = 0):
    """The TranslucentObject an observations file of `translucent trace` names."""
    from ..fit.translucent_observations import traced_object

    _check_suffix(observations, ".npz", "OBSERVATIONS")
    return traced_object(observations, seed)


def _environment(light: str, env_width: int):
    """The EnvironmentMap of a --light value, box-filtered to `env_width`."""
    from ..render.lights import environment_by_name

    return environment_by_name(environment_map(light), env_width)


def _view_bins(text: str) -> tuple[int, int]:
    """(theta, phi) bins of a --view-bins value THETAxPHI."""
    from ..core.errors import InputError
    try:
        theta, phi = (int(v) for v in text.lower().split("x"))
    except ValueError:
        theta = phi = 0
    if theta < 1 or phi < 1:
        raise InputError(f"--view-bins: expected THETAxPHI with positive integers (e.g. 8x16), got {text!r}")
    return theta, phi


def _light_count(cfg) -> int:
    """Directions of the light quadrature `cfg` asks for (the Gauss rule rounds to rings x points)."""
    from neumat.methods.neupress.prt import sphere_quadrature
    return sphere_quadrature(cfg.light_samples, cfg.light_rule)[1].shape[0]
