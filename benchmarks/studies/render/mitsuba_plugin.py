"""neumat materials inside Mitsuba 3's path tracer (`neumat.integrations.mitsuba`) against Mitsuba's own BSDFs.

    python benchmarks/studies/render/mitsuba_plugin.py
    python benchmarks/studies/render/mitsuba_plugin.py --res 128 --spp 64 --ref-spp 2048 \
        --image-out benchmarks/studies/render/results/mitsuba_plugin.png

Scene: the shared Stanford bunny (35k triangles) on a diffuse floor under the shared studio map, Mitsuba's `path`
integrator (--depth bounces, so indirect light between bunny and floor), --res^2 pixels, llvm_ad_rgb. Per
material, the bunny's BSDF is
  - Mitsuba's built-in equivalent (`diffuse`, anisotropic `roughconductor` with F = 1, `measured` for an RGL
    file), at --spp and, as the reference, at --ref-spp;
  - the same function as a neumat Material through the plugin, at --spp;
  - for the RGL file also NeuBRDF fitted to it (--fit-steps on the CPU) through the plugin, with cosine sampling
    (NeuBRDF has no sampler) and with the neural proxy sampler of Zeltner et al. fitted to it (--sampler-steps).
Columns: seconds per image (the same scene and spp, side by side in one run, all in the evaluated mode the plugin
needs), their ratio to the built-in in that mode and in Mitsuba's default symbolic mode (what a Mitsuba user gets
without the plugin), MSE / FLIP against the reference, and each image's maximum and mean (fireflies show in the
maximum; the plugin feeds the table as Mitsuba's `measured` does, so the RGL reader's row should match Mitsuba's).
"""
from __future__ import annotations

import argparse
import functools
import time
from dataclasses import replace

import numpy as np
import torch
from neumat.cli.common import print_table
from neumat.fit.method import recipe_for
from neumat.fit.trainer import fit
from neumat.integrations import mitsuba as plugin
from neumat.io.images import write_image_ldr
from neumat.io.shared_data import shared_data_dir
from neumat.metrics.image import image_metrics
from neumat.methods.neubrdf.model import NeuBRDF
from neumat.methods.neural_appearance.proxy_train import fit_sampler
from neumat.methods.neural_appearance.proxy_sampler import SampledMaterial
from neumat.reflectance.measured import RglMaterial
from neumat.viz.compare import compare_image


@functools.lru_cache(maxsize=None)
def bunny_to_world(mi, path: str):
    """The transform that scales the mesh at `path` to height 1 and stands it centred on y = 0 (read once)."""
    box = mi.load_dict({"type": "ply", "filename": path}).bbox()
    lo, hi = np.array(box.min), np.array(box.max)
    centre = (lo + hi) / 2
    return (mi.ScalarTransform4f().scale(1.0 / float(hi[1] - lo[1]))
            .translate([-float(centre[0]), -float(lo[1]), -float(centre[2])]))


def bunny_scene(mi, bsdf, res: int, spp: int, depth: int, data):
    """The bunny (scaled to height 1, standing on y = 0) on a 6 x 6 diffuse floor, camera in front and above."""
    bunny = str(data / "mesh" / "stanford_bunny_35k.ply")
    return mi.load_dict({
        "type": "scene", "integrator": {"type": "path", "max_depth": depth},
        "sensor": {"type": "perspective", "fov": 32,
                   "to_world": mi.ScalarTransform4f().look_at(origin=[0, 1.4, 3.2], target=[0, 0.45, 0], up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": res, "height": res, "rfilter": {"type": "box"}},
                   "sampler": {"type": "independent", "sample_count": spp}},
        "bunny": {"type": "ply", "filename": bunny, "to_world": bunny_to_world(mi, bunny), "bsdf": bsdf},
        "floor": {"type": "rectangle", "to_world": mi.ScalarTransform4f().rotate([1, 0, 0], -90).scale(3),
                  "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.5}}},
        "env": {"type": "envmap", "filename": str(data / "envmap" / "studio_small_03_1k.hdr")}})


def timed_render(mi, bsdf, args, data, spp: int, seed: int = 0, symbolic: bool = False):
    """(image (H, W, 3), seconds) of one render after a 1-spp warm-up that compiles the kernels; evaluated mode
    (as the plugin needs) unless `symbolic` (Mitsuba's default, for its built-in BSDFs only)."""
    scene = bunny_scene(mi, bsdf, args.res, spp, args.depth, data)

    def go(n, s):
        if symbolic:
            return torch.from_numpy(np.array(mi.render(scene, spp=n, seed=s), dtype=np.float32))
        return plugin.render(scene, spp=n, seed=s)
    go(1, 99)
    start = time.perf_counter()
    image = go(spp, seed)
    return image[..., :3], time.perf_counter() - start


def fitted_neubrdf(rgl: RglMaterial, args) -> NeuBRDF:
    torch.manual_seed(0)
    model = NeuBRDF()
    recipe = replace(recipe_for("neubrdf"), batch_size=args.batch)
    return fit(model, rgl, recipe, steps=args.fit_steps, device="cpu", progress=True).model.eval()


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--res", type=int, default=128)
    p.add_argument("--spp", type=int, default=64)
    p.add_argument("--ref-spp", type=int, default=2048)
    p.add_argument("--depth", type=int, default=6, help="Mitsuba path max_depth")
    p.add_argument("--rgl", default="vch_golden_yellow_rgb", help="shared RGL file (stem)")
    p.add_argument("--fit-steps", type=int, default=4000)
    p.add_argument("--batch", type=int, default=4096)
    p.add_argument("--sampler-steps", type=int, default=2000)
    p.add_argument("--image-out", default=None, help="comparison picture (.png)")
    args = p.parse_args()

    data = shared_data_dir()
    if data is None:
        raise SystemExit("this benchmark needs the shared data folder (../shared/data or NEUMAT_SHARED_DATA)")
    mi = plugin.register()
    rgl_path = data / "rgl" / f"{args.rgl}.bsdf"
    rgl = RglMaterial.from_file(rgl_path)
    t0 = time.perf_counter()
    neubrdf = fitted_neubrdf(rgl, args)
    fit_seconds = time.perf_counter() - t0
    t0 = time.perf_counter()
    sampler = fit_sampler(neubrdf, steps=args.sampler_steps, progress=True).sampler
    sampler_seconds = time.perf_counter() - t0

    cases = [
        ("lambert", {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.7, 0.5, 0.2]}},
         [("neumat lambert", lambda: plugin.bsdf("lambert:albedo=0.7/0.5/0.2"))]),
        ("anisotropic ggx", {"type": "roughconductor", "material": "none", "distribution": "ggx",
                             "alpha_u": 0.35, "alpha_v": 0.08},
         [("neumat ggx", lambda: plugin.bsdf("ggx:alpha_x=0.35,alpha_y=0.08,fresnel=none"))]),
        (args.rgl, {"type": "measured", "filename": str(rgl_path)},
         [("neumat RGL reader", lambda: plugin.bsdf(rgl)),
          ("NeuBRDF, cosine sampling", lambda: plugin.bsdf(neubrdf)),
          ("NeuBRDF + proxy sampler", lambda: plugin.bsdf(SampledMaterial(neubrdf, sampler)))]),
    ]
    # Mitsuba's symbolic virtual calls trace every live BSDF, so these run before any neumat BSDF exists
    symbolic = {material: timed_render(mi, builtin, args, data, args.spp, symbolic=True)[1]
                for material, builtin, _ in cases}
    rows, panels, metrics = [], {}, {}
    reference_for_picture = None
    for material, builtin, ours in cases:
        reference, ref_seconds = timed_render(mi, builtin, args, data, args.ref_spp, seed=1)
        base, base_seconds = timed_render(mi, builtin, args, data, args.spp)
        symbolic_seconds = symbolic[material]
        entries = [(f"Mitsuba {builtin['type']}", base, base_seconds)]
        entries += [(name, *timed_render(mi, make(), args, data, args.spp)) for name, make in ours]
        for name, image, seconds in entries:
            m = image_metrics(reference, image)
            mse = float((image - reference).pow(2).mean())
            rows.append({"material": material, "BSDF": name, "s / image": f"{seconds:.2f}",
                         "x built-in": f"{seconds / base_seconds:.1f}",
                         "x built-in symbolic": f"{seconds / symbolic_seconds:.1f}", "MSE vs ref": f"{mse:.3g}",
                         "FLIP vs ref": f"{m['flip']:.4f}", "max": f"{float(image.max()):.4g}",
                         "mean": f"{float(image.mean()):.4g}"})
            if material == args.rgl:
                panels[name], metrics[name] = image, {"MSE": mse, "FLIP": m["flip"], "s": seconds}
        rows.append({"material": material, "BSDF": f"reference ({args.ref_spp} spp)", "s / image": f"{ref_seconds:.2f}",
                     "x built-in": "", "x built-in symbolic": f"(built-in symbolic: {symbolic_seconds:.3f} s)",
                     "MSE vs ref": "", "FLIP vs ref": "", "max": f"{float(reference.max()):.4g}",
                     "mean": f"{float(reference.mean()):.4g}"})
        if material == args.rgl:
            reference_for_picture = reference
    print_table(f"{args.res}^2 pixels, {args.spp} spp, path max_depth {args.depth}; NeuBRDF fit {fit_seconds:.0f} s "
                f"({args.fit_steps} x {args.batch}), proxy sampler fit {sampler_seconds:.0f} s "
                f"({args.sampler_steps} steps)", rows, width=160)
    if args.image_out:
        write_image_ldr(args.image_out, compare_image(reference_for_picture, panels, metrics, tonemap="aces"))
        print(f"wrote {args.image_out}")


if __name__ == "__main__":
    main()
