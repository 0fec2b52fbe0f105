"""neupress: NeuPreSS (translucent objects) through the library's trainer: held-out error on a smooth synthetic
response, and the image table (issue 51's protocol) on an object traced by Mitsuba through the CLI users run
(`neumat translucent trace`, `neumat fit`), rendered under an environment map against a path-traced reference."""
from __future__ import annotations

import contextlib
import fcntl
import inspect
from pathlib import Path

import numpy as np
import torch

from neumat.core.query import Query
from neumat.fit.preset import build_fit
from neumat.fit.trainer import fit
from neumat.fit.translucent_observations import Observations
from neumat.viz.compare import compare_image
from neumat.warp.sphere import sample_uniform_sphere

from .. import harness
from .common import cli, default_budget, method_key, paper_budget, recipe_budget

NAME = "neupress"
DESCRIPTION = "NeuPreSS and the dipole baselines: held-out error over held-out variance, through the trainer"
MODELS = ["neupress", "dipole-bssrdf"]
BUDGET = {
    "quick": {"ours": "neupress (2 layers of 16) and the textured dipole, 20 steps on 2000 synthetic observations; "
                      "images: a sphere traced at 4 views x 8^2 rays x 4 paths, 20-step fits, 16^2 at 4 spp against "
                      "64 spp",
              "paper": paper_budget(MODELS[:1]) + " on a GPU", "expected_wall": "about 40 s"},
    "full": {"ours": f"CPU recipes: {recipe_budget(MODELS)}; 2^16 synthetic observations, seeds 0 and 1; images: the "
                     "Stanford bunny (marble / ketchup, 4 mm) traced by `neumat translucent trace` at its defaults "
                     "(8000 views x 32^2 rays x 256 paths), both models fitted at their defaults "
                     f"({default_budget(MODELS)}; seeds 0 and 1), a held-out set of 400 views x 4^2 rays x 4096 "
                     "paths, the full appearance at 64^2 under venice sunset (never used in development), 256 spp "
                     "MIS, against a 4096-spp Mitsuba reference and its second seed (the floor); then the same for the "
                     "paper's Paperweight as built here (`--scene paperweight`, traced at 20^2 rays a view)",
             "paper": paper_budget(MODELS[:1]) + " on a GPU, on path-traced observations of the bunny and kitten "
                      "(10^4 paths, 24-48 h per object); image FLIP 0.009-0.079 over its five scenes",
             "expected_wall": "about 3 h one job after another, about 2 h with --workers 2 (measured on the 2-core "
                              "Xeon, sessions 73-74: the bunny's trace 44.8 CPU min on both cores, each NeuPreSS fit "
                              "24.0-24.6 CPU min on one, each dipole fit 2.3-2.4, the test trace 0.8, references and "
                              "scoring a few minutes: about 100 CPU min; the paperweight's trace 25.4 CPU min, its "
                              "fits 25.3-25.8 and 2.4-2.5, its two 4096-spp references 20 s each: about 85 CPU min, "
                              "its fits 30 min wall with --workers 2); --work keeps traces, references and fits (a "
                              "cut-off fit resumes from its checkpoint) and --ledger each synthetic fit, image-table "
                              "row and figure, so a run can span sittings"},
}
#: its fits and image rows are independent jobs: --workers / --shard share them out (a table's traces and references
#: made once, locked); the image fits run on one core each, beside each other
SHARDS = True
SMALL = {"neupress": dict(features=16, width=16, layers=2, sampler_hidden=[8]),
         "dipole-bssrdf": dict(samples=16, texture_resolution=2)}


def observations(n: int, seed: int) -> Observations:
    """A smooth translucent response on a sphere of radius 0.5: a wrapped-cosine term times a spatial tint."""
    g = torch.Generator().manual_seed(seed)
    x = 0.5 * sample_uniform_sphere(torch.rand(n, 2, generator=g))
    normal = 2 * x
    wi = sample_uniform_sphere(torch.rand(n, 2, generator=g))
    value = (0.05 + 0.05 * (wi * normal).sum(-1, keepdim=True).clamp(min=0)) * (0.6 + 0.4 * normal.abs())
    return Observations(x=x, n=normal, wo=normal.clone(), wi=wi, value=value)


def run(run: harness.Run) -> None:
    """Fit each model, score held-out MSE over the held-out values' variance (1 = predicting the mean); each fit is
    a job of the run (`harness.Run.job`: under --ledger a run cut off keeps the fits it finished)."""
    n, steps = (2000, 20) if run.quick else (2 ** 16, None)
    seeds = [run.seed] if run.quick else [run.seed, run.seed + 1]
    test = observations(n // 4, 10_000)

    def synthetic(name: str, seed: int, overrides: dict) -> dict:
        train = observations(n, seed)
        model, setting = build_fit(name, "cpu", source=train, overrides=overrides, seed=seed)
        result = fit(model, train, setting.recipe, steps=steps, progress=False)
        with torch.no_grad():
            pred = result.model.eval(Query(test.wi, test.wo, x=test.x, n=test.n))
        return {"model": name, "seed": seed, "steps": result.steps, "fit s": result.seconds,
                "held-out mse / var": float(((pred - test.value) ** 2).mean() / test.value.var()),
                "bytes": model.size_bytes()}

    overrides = {name: SMALL[name] if run.quick else {} for name in MODELS}
    rows = [run.job(f"synthetic response x {name} (seed {seed})",
                    {"job": "synthetic", "model": name, "seed": seed, "observations": n, "steps": steps,
                     "overrides": overrides[name], **method_key(name, ["--preset", "cpu"])},
                    lambda name=name, seed=seed: synthetic(name, seed, overrides[name]), keep=lambda _: True)
            for seed in seeds for name in MODELS]
    run.table("fits", "Synthetic translucent response", [r for r in rows if r is not None])  # None: another shard's
    _images(run, seeds)


#: the image table's object, traced data, fits and rendering, full and quick
IMAGE_SETUP = {
    "full": {"scene": "mesh:{data}/mesh/stanford_bunny_35k.ply", "trace": [], "test": ["--images", "400",
             "--resolution", "4", "--spp", "4096"], "fit": {}, "light": "{data}/envmap/venice_sunset_1k.hdr",
             "resolution": 64, "spp": 256, "reference_spp": 4096},
    "quick": {"scene": "sphere", "trace": ["--images", "4", "--resolution", "8", "--spp", "4"],
              "test": ["--images", "8", "--resolution", "2", "--spp", "64"],
              "fit": {"neupress": ["--steps", "20", "--set", "features=16", "--set", "width=16", "--set", "layers=2",
                                   "--set", "sampler_hidden=8"],
                      "dipole-bssrdf": ["--steps", "20", "--set", "samples=16", "--set", "texture_resolution=2"]},
              "light": "sky", "resolution": 16, "spp": 4, "reference_spp": 64},
}
#: the paper's Paperweight (Table 1) as `neumat translucent trace --scene paperweight` builds it (docs/neupress.md):
#: the bunny's protocol, traced at 20^2 rays a view, not 32^2 (the cube covers about 2.4x the bunny's pixels: about as
#: many observations, and CPU minutes, as the bunny's trace); its own media and size
PAPERWEIGHT_SETUP = {**IMAGE_SETUP["full"], "scene": "paperweight", "trace": ["--resolution", "20"]}
#: the seed of the held-out views and paths (separate from every training seed)
TEST_SEED = 777


def _images(run: harness.Run, seeds: list[int]) -> None:
    """The image tables: the bunny (the sphere in a quick run), then in a full run the paperweight."""
    from neumat.core.errors import InputError
    from neumat.core.llvm import usable_libllvm
    from neumat.core.mitsuba import mitsuba_threads
    from neumat.io.shared_data import shared_data_dir

    setup = IMAGE_SETUP["quick" if run.quick else "full"]
    data = shared_data_dir()
    if not run.quick and data is None:
        run.skip("image table", "the bunny and the environment map are shared data (absent)")
        return
    try:
        usable_libllvm()
    except InputError as e:
        run.skip("image table", f"Mitsuba's LLVM backend is unavailable here: {e}")
        return
    with mitsuba_threads(run.threads):  # traces and references the same bit for bit at one thread, run to run
        _image_table(run, seeds, "images", "Image table: " + (
            "a traced sphere (numbers mean nothing; the suite runs)" if run.quick else
            "the bunny under a map never used in development (issue 51's protocol)"), setup, data,
            ["--media", "marble,ketchup", "--size-mm", "4"])
        if not run.quick:
            _image_table(run, seeds, "paperweight", "Image table: the paper's Paperweight (Table 1) as built here "
                         "(`--scene paperweight`), the bunny's protocol", PAPERWEIGHT_SETUP, data, [])


def _image_table(run: harness.Run, seeds: list[int], name: str, title: str, setup: dict, data, media: list[str]):
    """One object's image table: trace, fit each model per seed, score the held-out set and the full appearance
    against the reference (the second reference's scores are the floor). Each row is a job of the run: under --ledger
    a table finished in one sitting is not traced again in the next (the paperweight's takes hours more than the
    bunny's). Under --work the traces, references and fits are kept and reused (a fit while its model's default preset
    is unchanged), and a trace or fit cut off resumes (from its last checkpoint: at most 1000 steps lost)."""
    scene, light = (str(setup[k]).format(data=data) for k in ("scene", "light"))
    made: dict = {}  # the folder, traces and scorer, made by the first row the ledger does not hold
    held = contextlib.ExitStack()  # the folder, for as long as the table is built (a temporary one is removed after)

    def scorer() -> _Scorer:
        if not made:
            folder = held.enter_context(run.folder("images", setup, scene, trace_defaults()))
            train, test = folder / "train.npz", folder / "test.npz"
            with open(folder / "make.lock", "w") as lock:  # shards sharing the folder: one traces, the others wait
                fcntl.flock(lock, fcntl.LOCK_EX)
                for npz, options, seed in ((train, setup["trace"], run.seed), (test, setup["test"], TEST_SEED)):
                    args = ["translucent", "trace", "--scene", scene, *media, *options, "--seed", str(seed), "-q",
                            "--checkpoint", str(npz.with_suffix(".trace-checkpoint")), "--resume", "-o"]
                    _kept(npz, lambda out, args=args: cli([*args, str(out)]))
                made.update(folder=folder, train=train, scorer=_Scorer(folder, train, test, light, setup),
                            traced=Observations.load_source(train).get("trace_cpu_seconds"))  # absent before it
        return made["scorer"]

    def model_file(model: str, seed: int, preset: str) -> Path:
        scorer()
        nmat = made["folder"] / f"{model}-{seed}-{preset[:12]}.nmat"  # the preset's content: a new default refits
        return _kept(nmat, lambda out: cli(["fit", str(made["train"]), "--model", model, *setup["fit"].get(model, []),
                                            "--seed", str(seed), "--threads", str(run.threads), "-q",
                                            "--checkpoint", str(nmat.with_suffix(".checkpoint")), "--resume",
                                            "-o", str(out)]))

    def fitted(model: str, seed: int, preset: str) -> dict:
        nmat = model_file(model, seed, preset)
        traced = made["traced"]
        return {"model": model, "seed": seed, **scorer().model(nmat),
                "trace CPU min": None if traced is None else traced / 60}

    def picture(rows: list[dict], seed: int, presets: dict) -> dict:
        score = scorer()
        images = {f"{model} (seed {seed})": score.image(model_file(model, seed, presets[model])) for model in MODELS}
        images[rows[0]["model"]] = score.references[1]
        metrics = {f"{r['model']} (seed {r['seed']})" if r["seed"] is not None else r["model"]:
                   {k: r[k] for k in ("object FLIP", "FLIP", "SSIM")} for r in rows}
        return {"png": harness.png_base64(compare_image(score.references[0], images, metrics, tonemap="aces"))}

    # the scene as the setup names it (not the shared data's path on this machine), the trace's defaults and seed
    table_key = {"job": "image table", "table": name, "setup": setup, "media": media, "trace": trace_defaults(),
                 "trace seed": run.seed, "test seed": TEST_SEED}
    with held:
        rows = [run.job(f"{name}: reference, another seed (floor)", {**table_key, "row": "floor"},
                        lambda: {"model": "reference, another seed (floor)", "seed": None, **scorer().floor()},
                        keep=lambda _: True)]
        for seed in seeds:
            for model in MODELS:
                key = method_key(model, [])
                rows.append(run.job(f"{name}: {model} (seed {seed})",
                                    {**table_key, "row": model, "seed": seed, **key},
                                    lambda model=model, seed=seed, preset=key["preset"]: fitted(model, seed, preset),
                                    keep=lambda _: True))
        figure = None
        if all(r is not None for r in rows):  # in a shard, the last pass draws what other shards' rows show
            presets = {model: method_key(model, [])["preset"] for model in MODELS}
            shown = [rows[0]] + [r for r in rows[1:] if r["seed"] == seeds[0]]
            drawn = run.job(f"{name}: figure", {**table_key, "row": "figure", "seed": seeds[0], "presets": presets},
                            lambda: picture(shown, seeds[0], presets), keep=lambda _: True)
            if drawn is not None:
                figure = {"caption": f"Each row: the {setup['reference_spp']}-spp reference | the image scored "
                                     f"against it (seed {seeds[0]}'s models, then the reference's second seed, the "
                                     "floor) | its FLIP error (0 black, 1 yellow), ACES tone map", "png": drawn["png"]}
    run.protocol[name] = (f"the full appearance (surface reflection + subsurface + background) at "
                          f"{setup['resolution']}^2, {setup['spp']} spp MIS, against a {setup['reference_spp']}-"
                          "spp Mitsuba reference, ACES tone map; object FLIP over the object's pixels; the "
                          "floor row is a second reference (another seed) scored the same way; held-out: mean "
                          "and median squared error over the held-out values' variance (its mean is carried by "
                          "a few observations, so the median ranks); the budget: 'trace CPU min' the training "
                          "trace's CPU (all threads, as `neumat translucent trace` records it), 'fit CPU min' the "
                          "fit's (as `neumat fit` records it in the model file)")
    run.table(name, title, [r for r in rows if r is not None], figure=figure)  # None: another shard's row


def trace_defaults() -> dict:
    """The defaults the image table traces at: `neumat translucent trace`'s options, `collect_observations`' and
    `TranslucentConfig`'s. Part of the table's folder key, so that a kept trace is traced again when they change (as
    a kept fit is refitted when its preset changes)."""
    from neumat.cli.translucent import trace
    from neumat.core.config import config_to_dict
    from neumat.fit.translucent_observations import collect_observations
    from neumat.reflectance.translucent import TranslucentConfig

    def defaults(function) -> dict:  # the options that change what is traced
        return {name: getattr(p.default, "default", p.default) for name, p in
                inspect.signature(function).parameters.items()
                if name not in ("checkpoint", "resume", "checkpoint_every_s", "progress", "quiet")}
    return {"cli": defaults(trace), "observations": defaults(collect_observations),
            "object": config_to_dict(TranslucentConfig())}


def _kept(path: Path, make) -> Path:
    """`path`, made by make(partial path) unless it is already there (written whole: renamed when done)."""
    if not path.exists():
        partial = path.with_name(f"{path.stem}.partial{path.suffix}")
        make(partial)
        partial.rename(path)
    return path


class _Scorer:
    """Scores models of one traced object: held-out error on the test set and the image against the reference."""

    def __init__(self, folder: Path, train: Path, test: Path, light: str, setup: dict) -> None:
        from neumat.fit.translucent_observations import Observations, traced_object
        from neumat.render.lights import environment_by_name
        from neumat.render.translucent import object_mask, orbit_camera, render_translucent_reference

        self.setup, self.obj = setup, traced_object(train)
        self.env = environment_by_name(light, 128)
        self.camera = orbit_camera(self.obj, setup["resolution"])
        self.mask = object_mask(self.obj, self.camera, setup["resolution"]).numpy()
        self.references = []
        for k in (1, 2):
            path = folder / f"reference-{k}.npy"
            _kept(path, lambda out: np.save(out, render_translucent_reference(
                self.obj, self.env, self.camera, setup["resolution"], spp=setup["reference_spp"], seed=k,
                appearance="full").numpy()))
            self.references.append(torch.from_numpy(np.load(path)))
        self.test = Observations.load(test)

    def floor(self) -> dict:
        return self._image(self.references[1])

    def model(self, nmat: Path) -> dict:
        from neumat.catalog.modelfile import load_model
        from neumat.io.modelfile import read_header

        model = load_model(nmat, device="cpu")
        t = self.test
        with torch.no_grad():
            pred = torch.cat([model.eval(Query(wi=t.wi[i:i + 8192], wo=t.wo[i:i + 8192], x=t.x[i:i + 8192],
                                               n=t.n[i:i + 8192])) for i in range(0, len(t), 8192)])
        err = ((pred.double() - t.value.double()) ** 2).mean(-1) / t.value.double().var(0).mean()
        image = self.render(model, nmat)
        fit_cpu = read_header(nmat)["metrics"].get("fit_cpu_seconds")  # absent from fits made before it
        return {"held-out mean": float(err.mean()), "held-out median": float(err.median()), **self._image(image),
                "bytes": model.size_bytes(), "fit CPU min": None if fit_cpu is None else fit_cpu / 60}

    def render(self, model, nmat: Path) -> torch.Tensor:
        """`model`'s image at the table's protocol, also kept beside its file `nmat` (for the figure)."""
        from neumat.render.translucent import render_translucent

        image = render_translucent(model, self.obj, self.env, self.camera, self.setup["resolution"],
                                   spp=self.setup["spp"], seed=0, appearance="full")
        path = nmat.with_suffix(".image.npy")
        path.unlink(missing_ok=True)
        _kept(path, lambda out: np.save(out, image.numpy()))
        return image

    def image(self, nmat: Path) -> torch.Tensor:
        """The image its row scored: kept, or rendered again (a row made before images were kept)."""
        from neumat.catalog.modelfile import load_model

        path = nmat.with_suffix(".image.npy")
        return torch.from_numpy(np.load(path)) if path.exists() else self.render(load_model(nmat, device="cpu"), nmat)

    def _image(self, image: torch.Tensor) -> dict:
        from neumat.render.translucent import image_scores

        s = image_scores(self.references[0], image, self.mask)
        return {"FLIP": s["flip"], "object FLIP": s["object_flip"], "MSE": s["mse"], "SSIM": s["ssim"]}
