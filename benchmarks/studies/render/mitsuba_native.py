"""NeuBRDF in Mitsuba 3 natively (its Dr.Jit runtime, `neumat.integrations.mitsuba_native`) against Mitsuba's own
BSDFs and the torch bridge: seconds per image of the same scene, one run, one Dr.Jit thread.

    python benchmarks/studies/render/mitsuba_native.py --model paper_white.nmat
    # the model: neumat fit ../shared/data/rgl/paper_white_rgb.bsdf -o paper_white.nmat --steps 300 --threads 1

Scene: the bunny scene of `mitsuba_plugin.py` (shared Stanford bunny on a diffuse floor under the studio map, path
integrator, --depth), --res^2 pixels, --spp, llvm_ad_rgb. Rows: Mitsuba `roughconductor` (GGX, alpha 0.2) and
`measured` (the RGL file the model was fitted to) in Mitsuba's default symbolic mode and in evaluated mode; the
torch bridge with the NeuBRDF (evaluated mode, all it can run in); the native runtime in symbolic mode (the
default) and in evaluated mode, and with its MLP as `drjit.nn` cooperative vectors (`mlp_form: coopvec`, the CUDA
default) instead of LLVM's default constant-weight fma chains. Each time is the best of --repeats renders after a
warm-up render that compiles the kernels, with the row's scene the only one alive (other live scenes slowed a
Mitsuba BSDF's render by up to ~15 %); ratios are to `measured` symbolic and to `roughconductor` symbolic, measured
in the same run. A second table (same run): a UV-mapped
sphere on the same floor under the same map, Mitsuba `roughconductor` against the multiscale model (--multiscale,
default the paper's configuration at its initialisation) and neural-appearance with its learned sampler
(--neural-appearance, default its configuration at its initialisation) natively (symbolic and evaluated) and
through the bridge.
"""
from __future__ import annotations

import argparse
import gc
import time

import numpy as np


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--model", required=True, help="a NeuBRDF .nmat fitted to --rgl")
    p.add_argument("--rgl", default="paper_white_rgb", help="shared RGL file (stem) the model was fitted to")
    p.add_argument("--res", type=int, default=128)
    p.add_argument("--spp", type=int, default=16)
    p.add_argument("--depth", type=int, default=6)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--multiscale", default=None,
                   help="a multiscale .nmat for the UV-mapped table (default: the paper's configuration, 1024^2 x 8 "
                        "spatial latents, at its initialisation: the cost does not depend on the fit)")
    p.add_argument("--neural-appearance", default=None,
                   help="a neural-appearance .nmat (runtime form, with its learned sampler) for the UV-mapped table "
                        "(default: the paper's configuration, 256^2 x 8 latents, at its initialisation)")
    p.add_argument("--no-multiscale", action="store_true", help="only the NeuBRDF table")
    args = p.parse_args()

    from neumat.io.shared_data import shared_data_dir
    data = shared_data_dir()
    if data is None:
        raise SystemExit("this benchmark needs the shared data folder (../shared/data or NEUMAT_SHARED_DATA)")
    import torch
    torch.set_num_threads(1)
    from neumat.integrations import mitsuba as plugin
    mi = plugin.register("llvm_ad_rgb")
    import drjit as dr
    dr.set_thread_count(1)
    from benchmarks.studies.render.mitsuba_plugin import bunny_scene

    rgl = str(data / "rgl" / f"{args.rgl}.bsdf")
    cases = [("Mitsuba roughconductor (GGX, alpha 0.2)", {"type": "roughconductor", "distribution": "ggx",
                                                          "alpha": 0.2}, False),
             ("Mitsuba measured", {"type": "measured", "filename": rgl}, False),
             ("Mitsuba measured, evaluated mode", {"type": "measured", "filename": rgl}, True),
             ("neumat torch bridge, NeuBRDF (evaluated mode)", {"type": "neumat", "filename": args.model,
                                                                "native": False}, True),
             ("neumat native Dr.Jit runtime, NeuBRDF (symbolic)", {"type": "neumat", "filename": args.model}, False),
             ("neumat native Dr.Jit runtime, NeuBRDF, evaluated mode", {"type": "neumat", "filename": args.model},
              True),
             ("neumat native Dr.Jit runtime, NeuBRDF, drjit.nn coopvec MLP (symbolic)",
              {"type": "neumat", "filename": args.model, "mlp_form": "coopvec"}, False)]
    first_uv = len(cases)
    if not args.no_multiscale:
        ms = args.multiscale or _default_multiscale()
        cases += [("Mitsuba roughconductor (GGX, alpha 0.2)", {"type": "roughconductor", "distribution": "ggx",
                                                              "alpha": 0.2}, False),
                  ("neumat native Dr.Jit runtime, multiscale (symbolic)", {"type": "neumat", "filename": ms}, False),
                  ("neumat native Dr.Jit runtime, multiscale, evaluated mode", {"type": "neumat", "filename": ms},
                   True),
                  ("neumat torch bridge, multiscale (evaluated mode)", {"type": "neumat", "filename": ms,
                                                                       "native": False}, True)]
        na = args.neural_appearance or _default_neural_appearance()
        cases += [("neumat native Dr.Jit runtime, neural-appearance with its learned sampler (symbolic)",
                   {"type": "neumat", "filename": na}, False),
                  ("neumat native Dr.Jit runtime, neural-appearance with its learned sampler, evaluated mode",
                   {"type": "neumat", "filename": na}, True),
                  ("neumat torch bridge, neural-appearance with its learned sampler (evaluated mode)",
                   {"type": "neumat", "filename": na, "native": False}, True)]

    def timed(i: int) -> tuple[float, np.ndarray]:
        """Best of --repeats renders of case i after a warm-up render, its scene the only one alive (module
        docstring)."""
        _, bsdf, evaluated = cases[i]
        make = bunny_scene if i < first_uv else sphere_scene
        scene = make(mi, bsdf, args.res, args.spp, args.depth, data)
        best = float("inf")
        with plugin.evaluated_mode() if evaluated else _null():
            for seed in range(args.repeats + 1):  # seed 0: the warm-up that compiles the kernels
                start = time.perf_counter()
                image = mi.render(scene, spp=args.spp, seed=seed)
                dr.eval(image)
                dr.sync_thread()
                if seed:
                    best = min(best, time.perf_counter() - start)
        image = np.array(image)
        del scene
        gc.collect()
        dr.flush_malloc_cache()
        return best, image

    best, images = map(list, zip(*(timed(i) for i in range(len(cases)))))
    measured, ggx = best[1], best[0]
    print(f"{args.res}^2 pixels, {args.spp} spp, path max_depth {args.depth}, bunny scene, llvm_ad_rgb, one Dr.Jit "
          f"thread, best of {args.repeats}; model {args.model}")
    print("| BSDF in the same scene | seconds | x Mitsuba `measured` (symbolic) | x `roughconductor` | image mean |")
    print("|---|---|---|---|---|")
    for (name, _, _), seconds, image in zip(cases[:first_uv], best, images):
        print(f"| {name} | {seconds:.3f} | {seconds / measured:.2f} | {seconds / ggx:.2f} | "
              f"{float(np.mean(image[..., :3])):.4f} |")
    if len(cases) > first_uv:
        ggx = best[first_uv]
        print(f"\nUV-mapped scene (sphere with Mitsuba's uv on the same floor under the same map), same run; models "
              f"{ms}, {na}")
        print("| BSDF in the same scene | seconds | x `roughconductor` | image mean |")
        print("|---|---|---|---|")
        for (name, _, _), seconds, image in list(zip(cases, best, images))[first_uv:]:
            print(f"| {name} | {seconds:.3f} | {seconds / ggx:.2f} | {float(np.mean(image[..., :3])):.4f} |")


def _default_multiscale() -> str:
    """A .nmat of the paper's multiscale configuration at its initialisation (in a temporary folder)."""
    import tempfile
    from pathlib import Path

    import torch
    from neumat.catalog.modelfile import save_model
    from neumat.methods.latent_mlp.multiscale import MultiScale

    torch.manual_seed(0)
    path = Path(tempfile.mkdtemp(prefix="neumat_bench_")) / "multiscale.nmat"
    return str(save_model(MultiScale().train(False), path))


def _default_neural_appearance() -> str:
    """A .nmat of neural-appearance's default configuration (256^2 x 8 latents, two learned frames, the
    anisotropic two-lobe learned sampler) at its initialisation, runtime form (in a temporary folder)."""
    import tempfile
    from pathlib import Path

    import torch
    from neumat.catalog.modelfile import save_model
    from neumat.methods.neural_appearance.model import NeuralAppearance

    torch.manual_seed(0)
    path = Path(tempfile.mkdtemp(prefix="neumat_bench_")) / "neural_appearance.nmat"
    return str(save_model(NeuralAppearance().train(False).runtime(), path))


def sphere_scene(mi, bsdf, res: int, spp: int, depth: int, data):
    """A unit sphere (Mitsuba's uv: longitude, latitude) standing on the floor of `bunny_scene`, same camera, map."""
    return mi.load_dict({
        "type": "scene", "integrator": {"type": "path", "max_depth": depth},
        "sensor": {"type": "perspective", "fov": 32,
                   "to_world": mi.ScalarTransform4f().look_at(origin=[0, 1.4, 3.2], target=[0, 0.45, 0], up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": res, "height": res, "rfilter": {"type": "box"}},
                   "sampler": {"type": "independent", "sample_count": spp}},
        "ball": {"type": "sphere", "center": [0, 0.5, 0], "radius": 0.5, "bsdf": bsdf},
        "floor": {"type": "rectangle", "to_world": mi.ScalarTransform4f().rotate([1, 0, 0], -90).scale(3),
                  "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.5}}},
        "env": {"type": "envmap", "filename": str(data / "envmap" / "studio_small_03_1k.hdr")}})


class _null:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


if __name__ == "__main__":
    main()
