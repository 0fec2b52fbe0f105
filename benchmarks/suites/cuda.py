"""cuda: the models on a CUDA GPU, where the papers time them: the device's matrix-product bounds; every registered
model's torch runtime at 2^16, 2^20 and 2^22 queries per wall second and its agreement with the CPU; the Dr.Jit
runtime on drjit.cuda (fp16 cooperative vectors on tensor cores, and fp32) with its rate and its agreement with the
torch model; NeuBRDF's paper recipe fitted on the GPU with its step time. Measures, asserts nothing. Without a CUDA
device a quick run does the same on the CPU (torch, Dr.Jit's LLVM backend) at small sizes, so its code is tested
where CI runs; a full run records the skip."""
from __future__ import annotations

import copy
import math
import time
import warnings
from dataclasses import replace

import torch

from neumat.catalog.open_material import open_material
from neumat.fit.preset import build_fit
from neumat.fit.trainer import FitWarning, fit
from neumat.io.shared_data import shared_data_dir

from .. import harness
from . import speed

NAME = "cuda"
DESCRIPTION = ("every model's torch runtime and Dr.Jit runtime on a CUDA GPU: rates per wall second, agreement "
               "with the CPU, the device's matrix bounds, a paper-recipe NeuBRDF fit")
#: a batch whose one call would take longer than this (projected from the previous size's rate) is skipped
MAX_SECONDS_PER_CALL = 1.0
#: queries of the agreement checks
CHECK_QUERIES = 4096
#: the paper-recipe fit runs only when its projected wall time (from its first steps) is below this
MAX_FIT_SECONDS = 150.0
BUDGET = {
    "quick": {"ours": "on the CPU when no GPU is present: ggx, nbrdf, neubrdf, neural-appearance and multiscale at "
                      "2^10 queries, agreement on 256, the Dr.Jit runtime (LLVM without a GPU) of neubrdf, and 4 "
                      "steps of NeuBRDF's paper recipe at batch 2^10",
              "paper": "NeuBRDF Table 5 (RTX 3090 / 4090 timings), Timonen et al. Table 6 (RTX 3080 / 4090)",
              "expected_wall": "about 20 s"},
    "full": {"ours": "every registered model at 2^16, 2^20 and 2^22 queries (a call projected over "
                     f"{MAX_SECONDS_PER_CALL:g} s skipped), best of the run's repeats per wall second after "
                     f"torch.cuda.synchronize; agreement with the CPU on {CHECK_QUERIES} queries; the Dr.Jit "
                     "runtime of every model with a drjit export at fp16 (fp32 too for nbrdf, neubrdf, multiscale and "
                     "neural-appearance) at 2^16 and 2^20; their native BSDFs rendered by Mitsuba (512^2, 64 spp); "
                     "NeuBRDF's paper recipe (20000 steps at 2^14) on paper_white (GGX without the shared data)",
             "paper": "NeuBRDF Table 5 (RTX 3090 / 4090 timings), Timonen et al. Table 6 (RTX 3080 / 4090)",
             "expected_wall": "about 80 s on an H200 (measured 76 s: results/cuda/h200.json); a full run is "
                              "skipped"},
}


def run(run: harness.Run) -> None:
    """Fill the run's tables on the GPU (or, quick and without one, on the CPU)."""
    cuda = torch.cuda.is_available()
    if not cuda and not run.quick:
        run.skip("every table", "no CUDA device (torch.cuda.is_available() is False)")
        return
    dev = torch.device("cuda" if cuda else "cpu")
    run.protocol["device"] = torch.cuda.get_device_name(0) if cuda else "cpu (no CUDA device: the code path only)"
    run.protocol["timer"] = ("wall seconds of one call between torch.cuda.synchronize / drjit.sync_thread, best of "
                             "the run's repeats after a warm-up call (the suite's CPU-second timer does not see a "
                             "GPU); rates are queries / that time")
    _bounds(run, dev)
    materials = speed._materials(run)
    _torch_rates(run, materials, dev)
    _drjit(run, materials, cuda)
    _renders(run, materials, cuda)
    _paper_fit(run, dev)


def _wall(fn, dev: torch.device, repeats: int) -> float:
    """Best wall seconds of fn() over `repeats` calls after one warm-up, each ended by a device synchronise."""
    sync = torch.cuda.synchronize if dev.type == "cuda" else (lambda: None)
    with torch.no_grad():
        fn()
        sync()
        best = math.inf
        for _ in range(repeats):
            t0 = time.perf_counter()
            fn()
            sync()
            best = min(best, time.perf_counter() - t0)
    return best


def _bounds(run: harness.Run, dev: torch.device) -> None:
    """fp32 (no TF32), TF32 and fp16 matrix products of 4096^2 (512^2 on the CPU) on the device."""
    n = 4096 if dev.type == "cuda" else 512
    rows = []
    for what, dtype, tf32 in (("fp32", torch.float32, False), ("tf32", torch.float32, True),
                              ("fp16", torch.float16, False)):
        if dev.type == "cpu" and what != "fp32":
            continue
        before = torch.backends.cuda.matmul.allow_tf32
        torch.backends.cuda.matmul.allow_tf32 = tf32
        try:
            a, b = (torch.randn(n, n, device=dev, dtype=dtype) for _ in range(2))
            seconds = _wall(lambda: a @ b, dev, max(run.repeats, 5))
        finally:
            torch.backends.cuda.matmul.allow_tf32 = before
        rows.append({"what": f"{what} matrix product {n}^2 (torch.mm, 2 n^3 FLOPs)", "TFLOP/s": 2 * n ** 3 / seconds
                     / 1e12})
    run.table("bounds", "The device's matrix-product rates", rows)


def _relative_error(got: torch.Tensor, ref: torch.Tensor) -> float:
    """max |got - ref| / max |ref| over the batch (a scale-free error that zeros below the horizon do not inflate)."""
    return float((got.double() - ref.double()).abs().max() / ref.double().abs().max().clamp(min=1e-30))


def _torch_rates(run: harness.Run, materials: dict, dev: torch.device) -> None:
    """Each material's runtime on the device: agreement with its CPU values, and rates at the suite's batches."""
    sizes = [2 ** 10] if run.quick else [2 ** 16, 2 ** 20, 2 ** 22]
    check_n = 256 if run.quick else CHECK_QUERIES
    rows = []
    for name, m in materials.items():
        run.progress(f"torch on {dev.type}: {name}")
        try:
            # learned models move; analytic and measured references have no `to` and evaluate where their
            # queries are (or fail there, recorded below)
            on_dev = copy.deepcopy(m).to(dev) if hasattr(m, "to") else m
            q = speed.queries(m, check_n, run.seed)
            with torch.no_grad():
                err = _relative_error(on_dev.eval(q.to(dev)).cpu(), m.eval(q))
        except Exception as e:  # noqa: BLE001  (a model that does not move: recorded, not fatal)
            run.skip(f"{name} on {dev.type}", f"{type(e).__name__}: {str(e).splitlines()[0][:160]}")
            continue
        flops = int(m.flops()) if callable(getattr(m, "flops", None)) else None
        seconds = None
        for n in sizes:
            if seconds is not None and seconds * 16 > MAX_SECONDS_PER_CALL:
                run.skip(f"{name} at {n} queries", f"projected over {MAX_SECONDS_PER_CALL:g} s per call")
                break
            q = speed.queries(m, n, run.seed).to(dev)
            try:
                seconds = _wall(lambda: on_dev.eval(q), dev, run.repeats)
            except torch.OutOfMemoryError:
                run.skip(f"{name} at {n} queries", "out of device memory")
                break
            rows.append({"material": name, "queries": n, "evals/s": n / seconds, "us/call": 1e6 * seconds,
                         "flops/query": flops, "TFLOP/s": None if flops is None else flops * n / seconds / 1e12,
                         "err vs cpu": err})
        del on_dev
    if dev.type == "cuda":
        torch.cuda.empty_cache()
    run.table("torch", f"The torch runtime on {dev.type}", rows,
              "runtime forms at their default (paper) configs (the speed suite's materials), without autograd; "
              f"'err vs cpu' = max |device - CPU| / max |CPU| on {check_n} queries; 'TFLOP/s' from the model's "
              "analytic FLOPs (neumat.metrics.flops), against the bounds above")


def _drjit(run: harness.Run, materials: dict, cuda: bool) -> None:
    """Every material with a drjit export on drjit.cuda (or LLVM without a GPU): rate and agreement with torch."""
    from neumat.core.errors import InputError
    from neumat.core.llvm import configure_llvm
    from neumat.export.drjit.format import drjit_models, export_drjit

    try:
        configure_llvm()  # before drjit loads (neumat.core.llvm); a GPU run needs no LLVM
    except InputError as e:
        if not cuda:
            run.skip("Dr.Jit runtime", f"no CUDA device and no usable LLVM: {e}")
            return
    try:
        import drjit as dr
    except ImportError:
        run.skip("Dr.Jit runtime", "drjit is not installed (pip install mitsuba)")
        return
    from neumat.export.drjit.runtime import load_runtime
    from neumat.testing.drjit_parity import drjit_arrays, drjit_eval

    backend = "cuda" if cuda else "llvm"
    names = ["neubrdf"] if run.quick else [k for k in materials if k in drjit_models()]
    sizes = [2 ** 10] if run.quick else [2 ** 16, 2 ** 20]
    if cuda:
        run.skip("Dr.Jit fp32 on CUDA of models other than " + ", ".join(RENDERED[1:]),
                 "fp32 runs the literal form there (weights as kernel constants: a wide MLP's kernel compiles "
                 "slowly); fp16, CUDA's default, covers every model")
    check_n = 256 if run.quick else CHECK_QUERIES
    rows = []
    for name in names:
        m = materials[name]
        run.progress(f"drjit ({backend}): {name}")
        try:
            exported = export_drjit(m, precision="fp32")
        except Exception as e:  # noqa: BLE001
            run.skip(f"drjit export of {name}", f"{type(e).__name__}: {str(e).splitlines()[0][:160]}")
            continue
        q = speed.queries(m, check_n, run.seed)
        with torch.no_grad():
            ref = m.eval(q)
        computes = ("fp32",) if not cuda else ("fp16", "fp32") if name in RENDERED[1:] else ("fp16",)
        for compute in computes:
            rt = load_runtime(exported.source(), backend, compute)
            err = _relative_error(drjit_eval(rt, q), ref)
            seconds = None
            for n in sizes:
                if seconds is not None and seconds * 16 > MAX_SECONDS_PER_CALL:
                    run.skip(f"drjit {name} {compute} at {n} queries", f"projected over {MAX_SECONDS_PER_CALL:g} s")
                    break
                args, kwargs = drjit_arrays(rt, speed.queries(m, n, run.seed))

                def call():
                    dr.eval(rt.eval(*args, **kwargs))
                    dr.sync_thread()
                seconds = _wall(call, torch.device("cpu"), run.repeats)
                rows.append({"material": name, "compute": compute, "queries": n, "evals/s": n / seconds,
                             "us/call": 1e6 * seconds, "err vs torch": err})
    run.table("drjit", f"The Dr.Jit runtime on drjit.{backend}", rows,
              "the model's drjit export loaded with `neumat.export.drjit.runtime.load_runtime` (fp16: cooperative "
              "vectors, the MLP in half precision; fp32: the same program in single precision); a call traces the "
              "program again and launches its cached kernel, so 'us/call' includes the trace; queries uploaded "
              f"once, outside the timing; 'err vs torch' = max |drjit - torch CPU| / max |torch| on {check_n} queries")


#: the models a render times: one of each family with a native (Dr.Jit) BSDF in Mitsuba
RENDERED = ("ggx", "nbrdf", "neubrdf", "multiscale", "neural-appearance")


def _renders(run: harness.Run, materials: dict, cuda: bool) -> None:
    """A sphere with each RENDERED model's native BSDF (`neumat.integrations.mitsuba_native`) on a diffuse floor
    under a constant sky, path traced by Mitsuba (cuda_ad_rgb; llvm_ad_rgb without a GPU), beside Mitsuba's own
    roughconductor in the same scene: wall seconds of a render after a first one that compiles its kernels."""
    from neumat.catalog.modelfile import save_model
    from neumat.core.errors import InputError
    from neumat.integrations import mitsuba_native

    import drjit as dr

    variant = "cuda_ad_rgb" if cuda else "llvm_ad_rgb"
    try:
        mi = mitsuba_native.register(variant)
    except (InputError, ImportError) as e:
        run.skip("Mitsuba renders", f"{variant} unavailable: {str(e).splitlines()[0][:160]}")
        return
    size, spp = (32, 4) if run.quick else (512, 64)
    names = ["neubrdf"] if run.quick else [n for n in RENDERED if n in materials]
    bsdfs = {"mitsuba roughconductor (alpha 0.2)": {"type": "roughconductor", "alpha": 0.2}}
    rows = []
    with run.folder("renders") as folder:
        for name in names:
            path = save_model(materials[name], folder / f"{name}.nmat")
            bsdfs[name] = {"type": "neumat", "filename": str(path)}
        for name, spec in bsdfs.items():
            run.progress(f"render ({variant}): {name}")
            bsdf = mi.load_dict(spec)
            native = name.startswith("mitsuba") or mitsuba_native.is_native(bsdf)
            scene = mi.load_dict({
                "type": "scene", "integrator": {"type": "path", "max_depth": 4},
                "sensor": {"type": "perspective", "fov": 30,
                           "to_world": mi.ScalarTransform4f().look_at(origin=[0, 1.5, 3.5], target=[0, 0, 0],
                                                                      up=[0, 1, 0]),
                           "film": {"type": "hdrfilm", "width": size, "height": size, "rfilter": {"type": "box"}},
                           "sampler": {"type": "independent", "sample_count": spp}},
                "sphere": {"type": "sphere", "bsdf": bsdf},
                "floor": {"type": "rectangle", "bsdf": {"type": "diffuse"},
                          "to_world": mi.ScalarTransform4f().translate([0, -1, 0]).rotate([1, 0, 0], -90).scale(3)},
                "sky": {"type": "constant", "radiance": {"type": "rgb", "value": 1.0}}})

            def render():
                image = mi.render(scene, seed=1)
                dr.eval(image)
                dr.sync_thread()
                return image
            t0 = time.perf_counter()
            image = render()
            first = time.perf_counter() - t0
            seconds = _wall(render, torch.device("cpu"), max(2, run.repeats // 2))
            rows.append({"bsdf": name, "native": native, "pixels": f"{size}^2", "spp": spp, "first s": first,
                         "wall s": seconds, "Msamples/s": size * size * spp / seconds / 1e6,
                         "mean": float(torch.tensor(image.numpy()).mean())})
    run.table("render", f"Mitsuba renders ({variant})", rows,
              "a sphere (the BSDF) on a diffuse floor under a constant sky, path tracer max_depth 4; 'first s' = "
              "the first render (tracing and kernel compilation), 'wall s' = the best later one; 'native' = the "
              "BSDF ran in Mitsuba's kernels (Dr.Jit runtime), not through the torch bridge")


def _paper_fit(run: harness.Run, dev: torch.device) -> None:
    """NeuBRDF's paper recipe (end-to-end VQ, 20000 steps at 2^14) on the device: step time from a probe of its first
    steps after a warm-up fit (the H200 run's probe without one projected 610 s for a fit of about 300-440 s), then
    the whole fit where it fits the suite's time, with its final and best loss."""
    data = shared_data_dir()
    source = open_material("ggx:roughness=0.2") if data is None else open_material(
        data / "rgl" / "paper_white_rgb.bsdf")
    label = "ggx:roughness=0.2" if data is None else "rgl:paper_white"
    model, setting = build_fit("neubrdf", "paper", device=dev, source=source, seed=run.seed)
    model = model.to(dev)
    recipe = setting.recipe
    if run.quick:
        recipe = replace(recipe, steps=4, batch_size=2 ** 10)
    probe = min(200, recipe.steps)
    rows = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FitWarning)  # the probe's few steps are timed, not judged
        fit(copy.deepcopy(model), source, replace(recipe, steps=min(20, recipe.steps), log_every=10 ** 9,
                                                  checkpoint_every=10 ** 9), progress=False, device=dev)  # warm-up
        t0 = time.perf_counter()
        fit(copy.deepcopy(model), source, replace(recipe, steps=probe, log_every=10 ** 9, checkpoint_every=10 ** 9),
            progress=False, device=dev)
        probe_s = time.perf_counter() - t0
    projected = probe_s / probe * recipe.steps
    rows.append({"what": f"{probe} steps after a warm-up", "source": label, "steps": probe, "batch": recipe.batch_size,
                 "wall s": probe_s, "ms/step": 1e3 * probe_s / probe, "final loss": None, "best loss": None})
    if projected > MAX_FIT_SECONDS:
        run.skip("the whole paper-recipe fit", f"projected {projected:.0f} s, over the suite's {MAX_FIT_SECONDS:g} s")
    else:
        run.progress(f"paper-recipe NeuBRDF fit on {dev.type}: {recipe.steps} steps, about {projected:.0f} s")
        t0 = time.perf_counter()
        result = fit(model, source, replace(recipe, log_every=max(recipe.steps // 20, 1),
                                            checkpoint_every=10 ** 9), progress=False, device=dev)
        seconds = time.perf_counter() - t0
        losses = [r["loss"] for r in result.history if "loss" in r]
        rows.append({"what": "whole fit", "source": label, "steps": recipe.steps, "batch": recipe.batch_size,
                     "wall s": seconds, "ms/step": 1e3 * seconds / recipe.steps,
                     "final loss": losses[-1] if losses else None, "best loss": min(losses) if losses else None})
    run.table("fit", f"NeuBRDF's paper recipe on {dev.type}", rows,
              "`build_fit('neubrdf', 'paper')` through the library's trainer (the paper's end-to-end VQ recipe: "
              "codebook features, log-cosine loss, step decay); wall seconds including query sampling and "
              "the source's evaluation; losses from the trainer's history (recipe loss, recorded every 1/20 of the "
              "steps)")
