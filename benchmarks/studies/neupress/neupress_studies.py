"""The NeuPreSS paper's studies on our data: the skip / layer ablation (Fig. 7), the translucency sweep (Fig. 5) and
the analytic baselines (Table 2's dipole rows), each a table of held-out error and image FLIP.

    python benchmarks/studies/neupress/neupress_studies.py --study skips --observations obs.npz   # {skips on, off} x layers 5, 7, 11
    python benchmarks/studies/neupress/neupress_studies.py --study translucency --sizes 1,4,16     # traces the sphere at each size
    python benchmarks/studies/neupress/neupress_studies.py --study baselines --observations obs.npz
    python benchmarks/studies/neupress/neupress_studies.py --study skips --quick                   # tiny budgets, about a minute

--observations: a file from `neumat translucent trace` (its object is rebuilt from the file for the held-out data
and the images); without it the sphere of `TranslucentConfig` (at --size-mm) is traced here with --images views of
--res^2 rays at --spp paths. Held-out: --test-images views at --res / 2 with their own lights, two traces of
--test-spp paths (benchmarks/studies/neupress/neupress.py's `held_out`: their mean, and its noise floor). Images: --image-res^2 under
the forest map, light importance sampling at --render-spp, FLIP (after ACES) and MSE against a --ref-spp Mitsuba
reference. Scores: held-out MSE relative to the held-out variance (1 = no better than the mean; the noise floor
over the variance is the best a perfect model scores).

Models: NeuPreSS at its Config defaults (only the studied fields changed), fitted by its recipe's appearance phase
(the light sampler is not trained: images use light sampling) with --steps steps (default: the recipe's); the
dipole, homogeneous and textured (`texture_resolution` --texture), over a --dipole-samples surface quadrature of the
object, by their recipe (default steps: the recipe's). Every other default is the recipe's or the Config's.
--quick: tiny budgets (a few hundred observations, tens of steps, 16^2 images), about a minute a study on 2 cores:
for trying the commands, not for numbers.
"""
from __future__ import annotations

import argparse
import time
from dataclasses import dataclass

import torch

from .neupress import environment, held_out

from neumat.cli.common import print_table
from neumat.core.config import config_from_dict
from neumat.core.query import Query
from neumat.fit.method import recipe_for
from neumat.fit.trainer import fit
from neumat.fit.translucent_fit import best_validation
from neumat.fit.translucent_observations import Observations, collect_observations
from neumat.metrics.image import image_metrics
from neumat.methods.baselines.dipole_bssrdf import DipoleBSSRDF
from neumat.methods.neupress.model import NeuPreSS

STUDIES = ("skips", "translucency", "baselines")
#: the paper's Fig. 7: skips on and off at 5, 7 and 11 layers
ABLATION = [{"skips": s, "layers": n} for n in (5, 7, 11) for s in (True, False)]
BASELINES = ("neupress", "dipole", "dipole-textured")
#: --quick: budgets of a trial run (overriding the defaults of the options below)
QUICK = dict(images=60, res=16, spp=8, test_images=2, test_spp=64, image_res=16, ref_spp=64, render_spp=4,
             steps=40, dipole_steps=40, dipole_samples=256, batch=1024)


@dataclass
class Setup:
    """One object's data: training observations, held-out ones and their noise floor, and the image reference
    (None without an object: rows then have no image scores)."""

    data: Observations
    test: Observations
    floor: float
    obj: object = None
    env: object = None
    camera: object = None
    reference: torch.Tensor | None = None


def neupress_fit(data: Observations, steps: int | None, batch: int | None, bounds, **config) -> tuple[NeuPreSS, dict]:
    """NeuPreSS(**config) fitted by the appearance phase of its recipe (no sampler phase): (model, fit record)."""
    torch.manual_seed(0)
    model = NeuPreSS(**config)
    recipe = recipe_for("neupress")
    appearance = steps if steps is not None else round(recipe.steps * recipe.phase_split[0])
    recipe.steps, recipe.phase_split = appearance, (1.0, 0.0)
    if batch is not None:
        recipe.batch_size = batch
    recipe.options["bounds"] = bounds
    return model, _record(fit(model, data, recipe, progress=False))


def dipole_fit(data: Observations, obj, samples: int, steps: int | None, texture: int = 1) -> tuple[DipoleBSSRDF, dict]:
    """The dipole (homogeneous for texture 1, else textured R^3) fitted by its recipe over the object's surface
    quadrature (the observed points' when obj is None): (model, fit record)."""
    model = DipoleBSSRDF(samples=samples, texture_resolution=texture)
    recipe = recipe_for("dipole-bssrdf")
    if obj is not None:
        model.set_surface(*(t.float() for t in obj.surface_samples(samples)))
        recipe.options["bounds"] = [obj.bbox_min.tolist(), obj.bbox_max.tolist()]
    return model, _record(fit(model, data, recipe, steps=steps, progress=False))


def _record(result) -> dict:
    best = best_validation(result.history)
    return {"fit s": result.seconds, "best step": best["step"] if best else None}


def score(model, setup: Setup, render_spp: int) -> dict:
    """Held-out MSE relative to the held-out variance and, with an object, image MSE and FLIP (after ACES)."""
    from neumat.render.translucent import render_translucent
    t = setup.test
    with torch.no_grad():
        pred = torch.cat([model.eval(Query(wi=t.wi[i:i + 8192], wo=t.wo[i:i + 8192], x=t.x[i:i + 8192],
                                           n=t.n[i:i + 8192])) for i in range(0, len(t), 8192)])
    row = {"held-out / variance": float(((pred - t.value) ** 2).mean() / t.value.var())}
    if setup.reference is not None:
        res = setup.reference.shape[0]
        with torch.no_grad():
            img = render_translucent(model, setup.obj, setup.env, setup.camera, res, spp=render_spp, strategy="light")
        row["image MSE"] = float(((img - setup.reference) ** 2).mean())
        row["FLIP"] = image_metrics(setup.reference.numpy(), img.numpy(), tonemap="aces")["flip"]
    return row


def skips_study(setup: Setup, a) -> list[dict]:
    """Fig. 7: NeuPreSS with skips on / off at each layer count of --layers."""
    rows = []
    for layers in a.layers:
        for skips in (True, False):
            model, rec = neupress_fit(setup.data, a.steps, a.batch, _bounds(setup), skips=skips, layers=layers)
            rows.append({"skips": "on" if skips else "off", "layers": layers, **score(model, setup, a.render_spp),
                         **rec, "KB fp16": model.size_bytes(sampler=False) // 1024})
    return rows


def baselines_study(setup: Setup, a) -> list[dict]:
    """NeuPreSS, the homogeneous dipole and the textured dipole on the same observations."""
    rows = []
    for name in a.models:
        if name == "neupress":
            model, rec = neupress_fit(setup.data, a.steps, a.batch, _bounds(setup))
        else:
            model, rec = dipole_fit(setup.data, setup.obj, a.dipole_samples, a.dipole_steps,
                                    a.texture if name == "dipole-textured" else 1)
        rows.append({"model": name, **score(model, setup, a.render_spp), **rec,
                     "KB fp16": model.size_bytes(**({"sampler": False} if name == "neupress" else {})) / 1024})
    return rows


def _bounds(setup: Setup):
    return None if setup.obj is None else [setup.obj.bbox_min.tolist(), setup.obj.bbox_max.tolist()]


def traced_setup(a, size_mm: float | None = None) -> Setup:
    """The Setup of --observations, or of the sphere traced here at size_mm (Mitsuba 3)."""
    from neumat.reflectance.translucent import TranslucentConfig, TranslucentObject
    from neumat.render.translucent import orbit_camera, render_translucent_reference
    if a.observations and size_mm is None:
        data = Observations.load(a.observations)
        source = Observations.load_source(a.observations) or {}
        if "object" not in source:
            raise SystemExit(f"{a.observations}: no object description (write it with `neumat translucent trace`)")
        obj = TranslucentObject(config_from_dict(TranslucentConfig, source["object"]), spp=source.get("spp", a.spp))
    else:
        obj = TranslucentObject(TranslucentConfig(size_mm=size_mm or a.size_mm), spp=a.spp)
        data = collect_observations(obj, a.images, a.res)
    test, floor = held_out(obj, a.test_images, max(a.res // 2, 1), a.test_spp)
    env = environment()
    camera = orbit_camera(obj, a.image_res)
    reference = render_translucent_reference(obj, env, camera, a.image_res, spp=a.ref_spp)
    return Setup(data, test, floor, obj, env, camera, reference)


def describe(setup: Setup) -> str:
    variance = float(setup.test.value.var())
    return (f"{len(setup.data)} observations; held-out {len(setup.test)}, variance {variance:.4g}, noise floor "
            f"{setup.floor / variance:.3f} of it")


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--study", choices=STUDIES, required=True)
    p.add_argument("--observations", default=None, help="a file from `neumat translucent trace` (skips, baselines)")
    p.add_argument("--sizes", default="1,4,16", help="translucency: size_mm of each traced sphere")
    p.add_argument("--size-mm", type=float, default=4.0, help="the sphere traced without --observations")
    p.add_argument("--layers", default="5,7,11", help="skips: layer counts")
    p.add_argument("--models", default=",".join(BASELINES), help=f"baselines / translucency: of {BASELINES}")
    p.add_argument("--images", type=int, default=1500)
    p.add_argument("--res", type=int, default=32)
    p.add_argument("--spp", type=int, default=32)
    p.add_argument("--test-images", type=int, default=12)
    p.add_argument("--test-spp", type=int, default=4096)
    p.add_argument("--image-res", type=int, default=64)
    p.add_argument("--ref-spp", type=int, default=4096)
    p.add_argument("--render-spp", type=int, default=32)
    p.add_argument("--steps", type=int, default=None, help="NeuPreSS appearance steps (default: the recipe's)")
    p.add_argument("--batch", type=int, default=None, help="NeuPreSS batch (default: the recipe's)")
    p.add_argument("--dipole-steps", type=int, default=None, help="dipole steps (default: its recipe's)")
    p.add_argument("--dipole-samples", type=int, default=4096, help="the dipole's surface quadrature")
    p.add_argument("--texture", type=int, default=8, help="texels per side of the textured dipole")
    p.add_argument("--quick", action="store_true", help="tiny budgets (QUICK), about a minute")
    p.add_argument("--threads", type=int, default=1, help="torch threads")
    a = p.parse_args(argv)
    if a.quick:
        for k, v in QUICK.items():
            setattr(a, k, v)
    torch.set_num_threads(a.threads)
    a.layers = [int(n) for n in a.layers.split(",") if n]
    a.models = [m for m in a.models.split(",") if m]
    if set(a.models) - set(BASELINES):
        raise SystemExit(f"--models: unknown {sorted(set(a.models) - set(BASELINES))} (known: {BASELINES})")
    t = time.perf_counter()
    if a.study == "translucency":
        rows = []
        for size in (float(s) for s in a.sizes.split(",") if s):
            setup = traced_setup(a, size)
            print(f"size {size:g} mm: {describe(setup)}")
            rows += [{"size mm": size, **r} for r in baselines_study(setup, a)]
            print_table(f"size {size:g} mm", [_fmt(r) for r in rows[-len(a.models):]], width=200)  # as it goes
        title = "translucency sweep (sphere, marble / ketchup)"
    else:
        setup = traced_setup(a)
        print(describe(setup))
        rows = skips_study(setup, a) if a.study == "skips" else baselines_study(setup, a)
        title = f"{a.study} study"
    print_table(f"{title}; FLIP of {a.image_res}^2 images at {a.render_spp} spp against {a.ref_spp} spp; "
                f"{time.perf_counter() - t:.0f} s", [_fmt(r) for r in rows], width=200)


def _fmt(row: dict) -> dict:
    return {k: (f"{v:.4g}" if isinstance(v, float) else v) for k, v in row.items()}


if __name__ == "__main__":
    main()
