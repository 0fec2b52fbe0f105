"""NeuPreSS on a path-traced translucent object: held-out error, size, fit time, evaluation speed, and
environment-lit images against the Mitsuba 3 reference.

    python benchmarks/studies/neupress/neupress.py                       # marble/ketchup sphere, defaults below
    python benchmarks/studies/neupress/neupress.py --images 3000 --spp 128 --steps 3000 --image-out benchmarks/studies/neupress/results/neupress.png
    python benchmarks/studies/neupress/neupress.py --shape ../shared/data/mesh/stanford_bunny_35k.ply --variants smooth

Data (Sec. 4.2 of the paper, scaled down): --images orthographic views of --res^2 jittered rays, each view with
its own light direction and camera direction, --spp paths per ray; held-out: --test-images views with their own
lights at --test-spp paths per ray, traced twice with different seeds so that the noise of the reference itself
is known ("noise floor": half the mean squared difference of the two traces).
Variants: "paper" (Fourier G ~ N(18, 1), 7 layers of 128, spherical angles), "low frequency" (G ~ N(0, 0.3^2))
and "smooth" (G ~ N(0, 0.1^2)), each fitted by its recipe (`methods/neupress/train.py`: the appearance phase on
random batches with a fraction held back for validation, keeping the weights of the best validation record, then the
light sampler); --steps, --sampler-steps and --batch override the recipe's steps of the two phases and batch size,
and every default not set here is the recipe's or `NeuPreSS.Config`'s. Scores: held-out MSE (linear RGB,
1/sr) and the same relative to the variance of the held-out values (1 = no better than their mean; the noise
floor over that variance is the best a perfect model could score).
Baselines: the dipole BSSRDF of a homogeneous medium (Jensen et al. 2001) over a --dipole-samples surface quadrature,
its six coefficients fitted to the same observations by its recipe (--dipole-steps overrides its steps); NeuMIP on
UV textures (`neumat.methods.baselines.neumip_uv`: 128^2 x 8 latents over the spherical UV projection, MLP 4 x 64 of the latent
and the local light and view directions), fitted by its recipe (--steps and --batch override it).
"surface BRDF on UV textures" (`surface-brdf-uv`, the same network read as a surface BRDF times the cosine) stands
in for the paper's NeRFactor row. --variants picks NeuPreSS variants (default all three; empty for none),
--baselines the baselines (default all).
Images: --image-res^2 pixels, subsurface radiance only, under the shared forest map (downsampled to 128 x 64):
the reference with --ref-spp paths per pixel; path tracing and the models at --render-spp, the models with
environment ("light") or model ("model") importance sampling; MSE, FLIP and SSIM against the reference and seconds
per image, in the same run.
"""
from __future__ import annotations

import argparse
import time

import torch
from neumat.cli.common import print_table
from neumat.methods.baselines.dipole_observed import dipole_predict
from neumat.methods.baselines.neumip_uv_targets import neumip_uv_predict
from neumat.fit.method import recipe_for
from neumat.fit.trainer import fit
from neumat.fit.translucent_fit import best_validation
from neumat.fit.translucent_observations import Observations, collect_observations
from neumat.io.shared_data import shared_data_dir
from neumat.metrics.image import image_metrics
from neumat.methods.baselines.dipole_bssrdf import DipoleBSSRDF
from neumat.models.registry import build_model
from neumat.methods.neupress.model import NeuPreSS
from neumat.reflectance.translucent import TranslucentConfig, TranslucentObject
from neumat.render.envmaps import downsample_envmap, read_envmap
from neumat.render.lights import EnvironmentMap
from neumat.render.translucent import orbit_camera, render_translucent, render_translucent_reference

VARIANTS = {"paper": {"feature_mean": 18.0, "feature_std": 1.0},
            "low frequency": {"feature_mean": 0.0, "feature_std": 0.3},
            "smooth": {"feature_mean": 0.0, "feature_std": 0.1}}
BASELINES = {"dipole": "dipole (homogeneous)", "neumip-uv": "NeuMIP on UV textures",
             "surface-brdf-uv": "surface BRDF on UV textures"}


def held_out(obj: TranslucentObject, images: int, res: int, spp: int) -> tuple[Observations, float]:
    """Held-out observations (mean of two traces) and the noise floor of that mean (its MSE to the truth)."""
    a = collect_observations(obj, images, res, spp=spp, seed=991)
    o = a.x.double() + 1e-3 * obj.diagonal * a.wo.double()
    second = torch.zeros_like(a.value, dtype=torch.float64)
    for light in torch.unique(a.wi, dim=0):
        m = (a.wi == light).all(-1)
        # fresh random numbers
        second[m] = obj.trace(o[m], -a.wo[m].double(), light.double(), spp=spp)
    floor = float(((a.value.double() - second) ** 2).mean() / 4)  # variance of the mean of two traces
    return Observations(a.x, a.n, a.wo, a.wi, ((a.value.double() + second) / 2).float()), floor


def environment(width: int = 128) -> EnvironmentMap:
    return EnvironmentMap(downsample_envmap(read_envmap(shared_data_dir() / "envmap" / "forest_slope_1k.hdr"), width))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--images", type=int, default=1500)
    p.add_argument("--res", type=int, default=32)
    p.add_argument("--spp", type=int, default=64)
    p.add_argument("--test-images", type=int, default=12)
    p.add_argument("--test-spp", type=int, default=8192)
    p.add_argument("--steps", type=int, default=None, help="appearance steps of NeuPreSS and steps of the UV "
                                                           "baselines (default: their recipes')")
    p.add_argument("--batch", type=int, default=None, help="batch size of NeuPreSS and the UV baselines (default: "
                                                           "their recipes')")
    p.add_argument("--sampler-steps", type=int, default=None, help="NeuPreSS sampler steps (default: its recipe's)")
    p.add_argument("--image-res", type=int, default=64)
    p.add_argument("--ref-spp", type=int, default=8192)
    p.add_argument("--render-spp", type=int, default=32)
    p.add_argument("--dipole-samples", type=int, default=4096, help="surface quadrature of the dipole baseline")
    p.add_argument("--dipole-steps", type=int, default=None, help="dipole steps (default: its recipe's)")
    p.add_argument("--image-out", default=None, help="write a comparison PNG here")
    p.add_argument("--shape", default="sphere", help="'sphere' or a closed PLY mesh (TranslucentConfig.shape)")
    p.add_argument("--variants", default=",".join(VARIANTS), help=f"NeuPreSS variants, of: {', '.join(VARIANTS)}")
    p.add_argument("--baselines", default=",".join(BASELINES), help=f"of: {', '.join(BASELINES)}")
    a = p.parse_args()
    chosen = [v for v in a.variants.split(",") if v]
    baselines = [b for b in a.baselines.split(",") if b]
    for option, names, known in (("--variants", chosen, VARIANTS), ("--baselines", baselines, BASELINES)):
        if set(names) - set(known):
            raise SystemExit(f"{option}: unknown {sorted(set(names) - set(known))} (known: {', '.join(known)})")
    torch.manual_seed(0)
    obj = TranslucentObject(TranslucentConfig(shape=a.shape), spp=a.spp)
    t = time.perf_counter()
    data = collect_observations(obj, a.images, a.res, progress=True)
    collect_s = time.perf_counter() - t
    t = time.perf_counter()
    test, floor = held_out(obj, a.test_images, a.res // 2, a.test_spp)
    test_s = time.perf_counter() - t
    paths = len(data) * a.spp
    print(f"training data: {len(data)} observations x {a.spp} paths in {collect_s:.0f} s "
          f"({paths / collect_s:.3g} paths/s, 2 traces each: with and without the interior); held-out: "
          f"{len(test)} x 2 x {a.test_spp} paths in {test_s:.0f} s; held-out variance "
          f"{float(test.value.var()):.4g}, noise floor {floor:.3g} ({floor / float(test.value.var()):.3f} of it)")
    bounds = (torch.tensor(obj.bbox_min).float(), torch.tensor(obj.bbox_max).float())

    env = environment()
    camera = orbit_camera(obj, a.image_res)
    t = time.perf_counter()
    reference = render_translucent_reference(obj, env, camera, a.image_res, spp=a.ref_spp)
    ref_s = time.perf_counter() - t
    t = time.perf_counter()
    traced = render_translucent_reference(obj, env, camera, a.image_res, spp=a.render_spp, seed=1)
    images = {"reference": reference, f"path tracing {a.render_spp} spp": traced}
    image_rows = [_image_row("path tracing (Mitsuba volpath)", traced, reference, time.perf_counter() - t)]
    rows = []
    for name, cfg in VARIANTS.items():
        if name not in chosen:
            continue
        model = NeuPreSS(**cfg)
        recipe = recipe_for("neupress")
        appearance = round(recipe.steps * recipe.phase_split[0])
        appearance, sampler = (a.steps if a.steps is not None else appearance,
                               a.sampler_steps if a.sampler_steps is not None else recipe.steps - appearance)
        recipe.steps = appearance + sampler
        recipe.phase_split = (appearance / recipe.steps, sampler / recipe.steps)
        if a.batch is not None:
            recipe.batch_size = a.batch
        recipe.options["bounds"] = [b.tolist() for b in bounds]
        result = fit(model, data, recipe)
        hist = [r for r in result.history if r["phase"] == "appearance"]
        kl = [r for r in result.history if r["phase"] == "sampler"]
        fit_s, sampler_s = hist[-1]["seconds"], kl[-1]["seconds"] - hist[-1]["seconds"]
        with torch.no_grad():
            pred = model.raw(test.wi, test.x, test.wo).clamp(min=0)
            t = time.perf_counter()
            for _ in range(3):
                model.raw(test.wi, test.x, test.wo)
            evals = 3 * len(test) / (time.perf_counter() - t)
        mse = float(((pred - test.value) ** 2).mean())
        rows.append({"variant": name, "held-out MSE": f"{mse:.4g}",
                     "rel. to variance": f"{mse / float(test.value.var()):.3f}",
                     "train MSE (noisy)": f"{hist[-1]['mse']:.4g}",
                     "best step": best_validation(result.history)["step"],
                     "final KL": f"{kl[-1]['kl']:.3f}", "fit s": f"{fit_s:.0f}+{sampler_s:.0f}",
                     "evals/s": f"{evals:.3g}", "KB fp32": model.size_bytes() // 1024})
        for strategy in ("light", "model"):
            t = time.perf_counter()
            img = render_translucent(model, obj, env, camera, a.image_res, spp=a.render_spp, strategy=strategy)
            image_rows.append(_image_row(f"{name}, {strategy} IS", img, reference, time.perf_counter() - t))
            images[f"{name}, {strategy} IS"] = img
    if "dipole" in baselines:
        rows.append(_dipole(obj, data, test, a, env, camera, reference, images, image_rows))
    for kind in ("neumip-uv", "surface-brdf-uv"):
        if kind in baselines:
            rows.append(_uv_baseline(kind, obj, bounds, data, test, a, env, camera, reference, images, image_rows))
    print_table(f"NeuPreSS, {len(data)} observations ({a.images} views x {a.spp} spp, 5% of them for validation); "
                f"held-out {len(test)}", rows, width=250)
    print_table(f"Images {a.image_res}^2 under the forest map at {a.render_spp} spp against a {a.ref_spp}-spp "
                f"reference ({ref_s:.0f} s; image mean {float(reference.mean()):.4g}); FLIP and SSIM after ACES",
                image_rows, width=250)
    if a.image_out:
        _save(images, a.image_out)


def _dipole(obj, data, test, a, env, camera, reference, images, image_rows) -> dict:
    """The homogeneous dipole baseline fitted to the same observations: its table row; adds its image."""
    model = DipoleBSSRDF(samples=a.dipole_samples)
    model.set_surface(*(t.float() for t in obj.surface_samples(a.dipole_samples)))
    t = time.perf_counter()
    hist = fit(model, data, steps=a.dipole_steps).history  # its recipe: the first 4096 held back validate
    fit_s = time.perf_counter() - t
    with torch.no_grad():
        pred = dipole_predict(model)(test)
        t = time.perf_counter()
        dipole_predict(model)(test)
        evals = len(test) / (time.perf_counter() - t)
    mse = float(((pred - test.value) ** 2).mean())
    t = time.perf_counter()
    with torch.no_grad():
        img = render_translucent(model, obj, env, camera, a.image_res, spp=a.render_spp, strategy="light")
    image_rows.append(_image_row("dipole (homogeneous), light IS", img, reference, time.perf_counter() - t))
    images["dipole, light IS"] = img
    sigma_a, sigma_s = (", ".join(f"{v:.3g}" for v in c.tolist()) for c in model.coefficients())
    print(f"dipole coefficients (1/object unit): sigma_a {sigma_a}; sigma_s' {sigma_s}")
    return {"variant": "dipole (homogeneous)", "held-out MSE": f"{mse:.4g}",
            "rel. to variance": f"{mse / float(test.value.var()):.3f}", "train MSE (noisy)": f"{hist[-1]['mse']:.4g}",
            "best step": best_validation(hist)["step"], "final KL": "-",
            "fit s": f"{fit_s:.0f}", "evals/s": f"{evals:.3g}", "KB fp32": "0 (6 numbers)"}


def _uv_baseline(kind, obj, bounds, data, test, a, env, camera, reference, images, image_rows) -> dict:
    """A UV-texture baseline (`neumip-uv` or `surface-brdf-uv`) fitted to the same observations: its table row;
    adds its image."""
    torch.manual_seed(0)
    model = build_model({"type": kind})
    label = BASELINES[kind]
    t = time.perf_counter()
    recipe = recipe_for(kind)
    if a.batch is not None:
        recipe.batch_size = a.batch
    recipe.options["bounds"] = [b.tolist() for b in bounds]
    hist = fit(model, data, recipe, steps=a.steps).history
    fit_s = time.perf_counter() - t
    with torch.no_grad():
        pred = neumip_uv_predict(model)(test).clamp(min=0)
        t = time.perf_counter()
        for _ in range(3):
            neumip_uv_predict(model)(test)
        evals = 3 * len(test) / (time.perf_counter() - t)
    mse = float(((pred - test.value) ** 2).mean())
    t = time.perf_counter()
    with torch.no_grad():
        img = render_translucent(model, obj, env, camera, a.image_res, spp=a.render_spp, strategy="light")
    image_rows.append(_image_row(f"{label}, light IS", img, reference, time.perf_counter() - t))
    images[f"{kind}, light IS"] = img
    return {"variant": label, "held-out MSE": f"{mse:.4g}",
            "rel. to variance": f"{mse / float(test.value.var()):.3f}", "train MSE (noisy)": f"{hist[-1]['mse']:.4g}",
            "best step": best_validation(hist)["step"], "final KL": "-",
            "fit s": f"{fit_s:.0f}", "evals/s": f"{evals:.3g}", "KB fp32": model.size_bytes() // 1024}


def _image_row(method: str, image: torch.Tensor, reference: torch.Tensor, seconds: float) -> dict:
    m = image_metrics(reference.numpy(), image.numpy(), tonemap="aces")
    return {"method": method, "seconds": f"{seconds:.1f}", "MSE": f"{float(((image - reference) ** 2).mean()):.3g}",
            "FLIP": f"{m['flip']:.3f}", "SSIM": f"{m['ssim']:.3f}"}


def _save(images: dict, path: str) -> None:
    from neumat.io.images import write_image_ldr
    from neumat.viz.compare import compare_image
    others = {k: v for k, v in images.items() if k != "reference"}
    metrics = {k: {"mse": float(((v - images["reference"]) ** 2).mean())} for k, v in others.items()}
    write_image_ldr(path, compare_image(images["reference"], others, metrics, tonemap="aces"))
    print(f"wrote {path}: reference | method | FLIP rows for " + ", ".join(others))


if __name__ == "__main__":
    main()
