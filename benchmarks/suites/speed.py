"""speed: every registered model in its shipped runtime form, analytic GGX and a measured RGL table: FLOPs per
query, evaluations and sample+pdf per CPU second at three batch sizes, % of this core's fp32 sgemm rate, cost
against GGX in the same process, the GLSL (llvmpipe), Slang (slangpy CPU) and Dr.Jit runtime (LLVM) exports' rates
(and the measured reference through Mitsuba's own `measured` plugin), training step
CPU time per phase at two batch sizes through the library's trainer, texture-set models at two texture sizes (issue 49
item 1; measures, asserts nothing)."""
from __future__ import annotations

import functools
import itertools
import statistics
import time
import warnings
from dataclasses import replace

import torch

from neumat.catalog.open_material import open_material
from neumat.core.query import Query
from neumat.fit.preset import DEFAULT_PRESET, build_fit
from neumat.fit.trainer import FitWarning, fit
from neumat.io.shared_data import shared_data_dir
from neumat.models.registry import load_all
from neumat.nn.latent_texture import LatentPyramid
from neumat.reflectance.btf import direction_set
from neumat.nn import cpu_kernels
from neumat.warp.hemisphere import sample_cosine_hemisphere
from neumat.warp.sphere import sample_uniform_sphere

from .. import harness

NAME = "speed"
DESCRIPTION = ("evaluations / sample+pdf per CPU second, FLOPs, % of sgemm, cost against GGX, export rates and "
               "training step time of every model")
#: a batch size whose one call would take longer than this (projected from the previous size's rate) is skipped:
#: the timer repeats every call at least 7 times
MAX_SECONDS_PER_CALL = 2.0
BUDGET = {
    "quick": {"ours": "ggx, nbrdf, neubrdf, neural-appearance and multiscale at batches of 2^10 and 2^12 queries, "
                      "best of 3; "
                      "the fixed cost of a call at batches of 1 and 64; exports of neubrdf only (GLSL fp32, its tables "
                      "as images (GLSL 4.20) and through samplers (3.30), beside GLSL GGX and Dr.Jit fp32 at "
                      "2^16 queries, Slang fp16 at 2^13); training steps of nbrdf, a small neubrdf and multiscale (on "
                      "32^2 and 64^2 crops) at batches 2^8 and 2^10",
              "paper": "none (the papers time on GPUs: NeuBRDF Table 5, Timonen et al. Table 6)",
              "expected_wall": "about 30 s"},
    "full": {"ours": "batches of 2^10, 2^16 and 2^20 queries (a batch whose one call would take over "
                     f"{MAX_SECONDS_PER_CALL:g} CPU s skipped), best of 7 samples of >= 0.05 CPU s, the better of "
                     "two passes over the models for evaluation rates; the fixed cost "
                     "of a call at batches of 1 and 64; every export "
                     "target; training steps of every BRDF / SVBRDF model at its default preset on the CPU recipe "
                     "(multiscale also at the paper's, 'cpu'), batches 2^10 and 2^13 (SVBRDF "
                     "models on a 64^2 crop, and on the whole 1K set at 2^13)",
             "paper": "none (the papers time on GPUs: NeuBRDF Table 5, Timonen et al. Table 6)",
             "expected_wall": "about 16 min on one thread (measured: 934 s wall on the idle Xeon VM at 75c50ad, "
                              "two passes of evaluation rates, every GLSL export under 4.20 and 3.30; "
                              "results/speed/full.json)"},
}
#: passes over every model of the evaluation table (by quick): each rate is the best over them, so that a few slow
#: minutes of a shared machine do not decide a row (the best-of-7 samples of one pass all fall within a second)
PASSES = {True: 1, False: 2}
#: the models a quick run times: one of each family that evaluates in milliseconds (every latent-texture model builds
#: a paper-sized 1024^2 pyramid first, about 1.5 s; one stands for the family)
QUICK_MODELS = ("ggx", "nbrdf", "neubrdf", "neural-appearance", "multiscale")
#: the measured reference (in the shared data folder), timed also through Mitsuba's own `measured` plugin
RGL_FILE = "rgl/paper_white_rgb.bsdf"


def run(run: harness.Run) -> None:
    """Fill the run's tables: machine bounds, evaluation rates, export rates, training step times."""
    sizes = [2 ** 10, 2 ** 12] if run.quick else [2 ** 10, 2 ** 16, 2 ** 20]
    sgemm = harness.sgemm_flops_per_second(repeats=run.repeats, min_seconds=run.min_seconds)
    run.table("bounds", "This core's bounds", [{"what": "fp32 sgemm (torch.mm 512^2, 2 n^3 FLOPs)",
                                                "GFLOP/s": sgemm / 1e9, "threads": torch.get_num_threads()}])
    run.protocol["flops"] = ("FLOPs per query: the model's analytic count `model.flops()` (neumat.metrics.flops."
                             "model_flops: 2 per multiply-add, as sgemm's 2 n^3); '% sgemm' = FLOPs x evaluations "
                             "per CPU second / the sgemm rate above; 'x GGX' = GGX's rate / the model's at the same "
                             "batch, measured in this process")
    materials = _materials(run)
    rates: dict[tuple, float] = {}  # (name, n, "eval" / "sample") -> the best rate over the passes
    for p in range(PASSES[run.quick]):
        for name, m in materials.items():
            run.progress(f"evaluation rates of {name} (pass {p + 1} of {PASSES[run.quick]})")
            rate = None
            for n in sizes:
                if p > 0 and (name, n, "eval") not in rates:  # skipped in the first pass
                    continue
                if rate is not None and n / rate > MAX_SECONDS_PER_CALL:  # the dipole's 8192-point quadrature
                    run.skip(f"{name} at {n} queries", f"one call would take about {n / rate:.0f} CPU s (at "
                             f"{rate:.3g} evaluations per CPU s), over the suite's {MAX_SECONDS_PER_CALL:g} s per call")
                    continue
                rate = _eval_rate(run, m, n)
                rates[(name, n, "eval")] = max(rate, rates.get((name, n, "eval"), 0.0))
                if m.can_sample:
                    sample = _sample_rate(run, m, n)
                    rates[(name, n, "sample")] = max(sample, rates.get((name, n, "sample"), 0.0))
    ggx = {n: rates[("ggx:roughness=0.2", n, "eval")] for n in sizes}
    rows = []
    for name, m in materials.items():
        flops = int(m.flops()) if callable(getattr(m, "flops", None)) else None
        path = _path(m, run.seed)
        for n in sizes:
            if (name, n, "eval") not in rates:
                continue
            rate = rates[(name, n, "eval")]
            rows.append({"material": name, "queries": n, "path": path, "flops/query": flops, "evals/cpu s": rate,
                         "sample+pdf/cpu s": rates.get((name, n, "sample")),
                         "% sgemm": None if flops is None else 100 * flops * rate / sgemm,
                         "x GGX": ggx[n] / rate})
    run.table("eval", "Evaluation and sampling rates (runtime form, one thread)", rows,
              "models at their default (paper) config, called without autograd (torch.no_grad) as renderers call "
              "them; dipole-bssrdf with its quadrature on a sphere of radius 0.5; 'path': the model's torch "
              "operations or a fused C kernel (neumat.nn.cpu_kernels); each rate the best of "
              f"{PASSES[run.quick]} pass(es) over every model, minutes apart (a shared VM's slow minutes otherwise "
              "decide a row: an idle run at a0553c3 read neumip-offset at 8.8 % sgemm, the same timer alone 19.9 %)")
    _texture_reads(run, materials, 2 ** 12 if run.quick else 2 ** 16, sgemm)
    _fixed_costs(run, materials)
    export_n = 2 ** 16
    runtime_rates = {r["material"]: r["evals/cpu s"] for r in rows if r["queries"] == export_n}
    if run.quick:  # its batches stop below the exports' (a full run has every material at export_n but those capped)
        for name in ("ggx:roughness=0.2", "neubrdf"):
            runtime_rates[name] = _eval_rate(run, materials[name], export_n)
    _exports(run, materials, export_n, runtime_rates, {r["material"]: r["path"] for r in rows}, sgemm)
    _training(run)
    tables = {t["name"]: t["rows"] for t in run.tables}
    run.table("targets", "Issue 49's targets on this run's tables", targets(tables, export_n),
              "each target against the tables above: '% sgemm' of the runtime forms at 2^16 queries, every eval "
              "call's fixed cost, GGX's per-query cost from 2^16 to 2^20, NeuBRDF's GLSL (llvmpipe, both "
              f"precisions) against its fp32 rate at cdd2d0c ({GLSL_NEUBRDF_BEFORE:.3g} evaluations per CPU s) and "
              "against its own runtime (the C kernel, and its torch operations), the 1K-set training step against "
              "the crop's; 'met' empty where this run did not measure it "
              "(--quick: its batches stop at 2^12)")


#: issue 49's targets ("What it must show"), checked on every run's own tables (`targets`)
BOUND_NEURAL_BRDF = 50.0      # % of sgemm at 2^16 queries: the NeuBRDF and NBRDF runtime forms
BOUND_LATENT = 15.0           # % of sgemm at 2^16 queries: the latent-texture family and neural-appearance
LATENT_FAMILY = ("multiscale", "tripleplane", "neumip", "neumip-frame", "neumip-offset", "nbrdf-uv",
                 "neural-appearance")
MAX_FIXED_US = 50.0           # fixed cost of an eval call
MAX_GGX_GROWTH = 1.5          # GGX's per-query cost at 2^20 queries over its cost at 2^16
GLSL_NEUBRDF_BEFORE = 1.66e5  # NeuBRDF's GLSL evaluations per CPU s on llvmpipe at cdd2d0c (the issue's table)
MIN_GLSL_GAIN = 10.0
MAX_GLSL_X_RUNTIME = 2.0      # NeuBRDF's GLSL cost over its own runtime's per core: the C kernel, and the
                              # torch operations the issue measured (the kernel came after it, 2x faster)
MAX_STEP_RATIO = 3.0          # a multiscale / neural-appearance step on the 1K set over the same step on a crop


def targets(tables: dict[str, list[dict]], n: int = 2 ** 16) -> list[dict]:
    """Issue 49's targets against a run's tables (name -> rows, as `run.tables` holds them): a row per target and
    model with the measured value, the bound and whether it is met (None: not measured in this run)."""
    rows = []

    def add(target: str, what: str, value: float | None, bound: str, met: bool) -> None:
        rows.append({"target": target, "what": what, "measured": value, "bound": bound,
                     "met": None if value is None else met})

    at = {(r["material"], r["queries"]): r for r in tables.get("eval", [])}
    for names, bound in ((("neubrdf", "nbrdf"), BOUND_NEURAL_BRDF), (LATENT_FAMILY, BOUND_LATENT)):
        for name in names:
            value = at.get((name, n), {}).get("% sgemm")
            add(f"% sgemm at {n} queries", name, value, f">= {bound:g}", value is not None and value >= bound)
    for row in tables.get("fixed", []):
        if row.get("fixed us") is not None:
            add("fixed cost of an eval call (us)", row["what"], row["fixed us"], f"<= {MAX_FIXED_US:g}",
                row["fixed us"] <= MAX_FIXED_US)
    for name in ("ggx:roughness=0.2", "ggx"):
        small, large = at.get((name, n)), at.get((name, 2 ** 20))
        growth = None if small is None or large is None else small["evals/cpu s"] / large["evals/cpu s"]
        add(f"per-query cost at {2 ** 20} over {n} queries", name, growth, f"<= {MAX_GGX_GROWTH:g}",
            growth is not None and growth <= MAX_GGX_GROWTH)
    # the issue timed fp32 (its fp16 was slower then); the paper ships fp16. The export's fastest GLSL (4.20: its
    # table as an image), and the GLSL 3.30 every export runs under (its table through the sampler)
    for precision, target in itertools.product(("fp32", "fp16"), ("glsl (llvmpipe)", "glsl 3.30 (llvmpipe)")):
        glsl = next((r for r in tables.get("exports", []) if r["material"] == "neubrdf" and r["queries"] == n
                     and r["target"] == target and r["precision"] == precision), None)
        if glsl is None and target != "glsl (llvmpipe)":
            continue
        what = f"neubrdf ({precision}{', GLSL 3.30' if target != 'glsl (llvmpipe)' else ''})"
        gain = None if glsl is None else glsl["evals/cpu s"] / GLSL_NEUBRDF_BEFORE
        add("GLSL rate over the fp32 rate at cdd2d0c", what, gain, f">= {MIN_GLSL_GAIN:g}",
            gain is not None and gain >= MIN_GLSL_GAIN)
        for column, runtime in (("x runtime", "its runtime's"), ("x torch ops", "its runtime's torch operations'")):
            slower = None if glsl is None else glsl.get(column)
            add(f"GLSL cost over {runtime}", what, slower, f"<= {MAX_GLSL_X_RUNTIME:g}",
                slower is not None and slower <= MAX_GLSL_X_RUNTIME)
    for row in tables.get("training", []):
        ratio = next((v for k, v in row.items() if k.startswith("x ") and v is not None), None)
        if ratio is not None and row["model"] in ("multiscale", "neural-appearance") \
                and row["texels"] == "1024^2" and row.get("preset", DEFAULT_PRESET) == DEFAULT_PRESET:
            add("1K-set training step over the crop's", f"{row['model']} ({row['phase']})", ratio,
                f"<= {MAX_STEP_RATIO:g}", ratio <= MAX_STEP_RATIO)
    return rows


def _path(m, seed: int, q: Query | None = None) -> str:
    """'C kernel' when an eval call of the material (on q's first 8 queries) runs a fused kernel (neumat.nn.cpu_kernels),
    else 'torch'."""
    q = queries(m, 8, seed) if q is None else q[:8]
    before = cpu_kernels.calls[0]
    with torch.no_grad():
        m.eval(q)
    return "C kernel" if cpu_kernels.calls[0] > before else "torch"


#: the texture reads a renderer asks for: the finest level, a trilinear read at a fixed level of detail, an
#: anisotropic footprint (the filter's axes 1e-3 and 3e-4 uv^2: two probes on a 1K texture); and the finest level at
#: uv in raster order (a camera facing the textured square: neighbouring queries read neighbouring texels, as a
#: renderer's do, where the speed suite's uniform uv read every texel at random)
READS = {"finest level": {}, "lod 2.3": {"lod": 2.3},
         "anisotropic footprint": {"footprint": ((1e-3, 0.0), (0.0, 3e-4))}, "finest level, raster uv": {"raster": True}}


def raster_uv(n: int) -> torch.Tensor:
    """n uv (n, 2) in raster order: pixel centres of a side x (n / side) image of the unit square, row by row
    (side = the largest power of 2 at most sqrt(n))."""
    side = 1 << (max(n, 1).bit_length() - 1) // 2
    k = torch.arange(n, dtype=torch.float64)
    return torch.stack([((k % side) + 0.5) / side, ((k // side) + 0.5) / (-(-n // side))], -1).float()


def _texture_reads(run: harness.Run, materials: dict, n: int, sgemm: float) -> None:
    """Evaluation rate of each model that reads a latent pyramid at uv (not a full sphere; the BTF models interpolate
    their texels whatever the lod) at n queries for each of READS."""
    rows = []
    for name, m in materials.items():
        if m.full_sphere or not isinstance(m, torch.nn.Module) \
                or not any(isinstance(sub, LatentPyramid) for sub in m.modules()):
            continue
        run.progress(f"texture reads of {name}")
        base = queries(m, n, run.seed)
        for read, extra in READS.items():
            q = base
            if "lod" in extra:
                q = replace(base, lod=torch.full((n,), extra["lod"]))
            elif "footprint" in extra:
                q = replace(base, footprint=torch.tensor(extra["footprint"]).expand(n, 2, 2).contiguous())
            elif "raster" in extra:
                q = replace(base, uv=raster_uv(n))
            rate = n / _runtime_time(run, lambda: m.eval(q))
            flops = int(m.flops()) if callable(getattr(m, "flops", None)) else None
            rows.append({"material": name, "queries": n, "read": read, "path": _path(m, run.seed, q),
                         "evals/cpu s": rate,
                         "% sgemm": None if flops is None else 100 * flops * rate / sgemm})
    run.table("reads", "Texture reads (one thread)", rows,
              "every model reading a latent texture at uv, at the speed suite's queries: at the finest level, "
              "trilinearly at lod 2.3, or through an anisotropic footprint diag(1e-3, 3e-4) uv^2 (what `neumat "
              "render` passes; two probes on a 1K texture), all at the suite's uniform random uv; and the finest "
              "level at uv in raster order (a camera facing the texture: neighbouring queries read neighbouring "
              "texels, as a renderer's do; the random reads of a 1K texture, 21-34 MB a latent, miss the caches); "
              "'% sgemm' against the bound above, the model's FLOPs not counting the extra texel reads")


def _fixed_costs(run: harness.Run, materials: dict) -> None:
    """CPU microseconds of one eval call at batches of 1 and 64 queries (the Query built and checked once, outside
    the timing), the fixed cost they imply (the intercept of the line through both: a call's cost less its queries'
    work, which for the dipole's quadrature is itself tens of microseconds a query), and of building a checked Query
    of one pair: the per-call cost small batches pay."""
    rows = []
    for name, m in materials.items():
        q1, q64 = queries(m, 1, run.seed), queries(m, 64, run.seed)
        one = min(1e6 * _runtime_time(run, lambda: m.eval(q1)) for _ in range(PASSES[run.quick]))
        many = min(1e6 * _runtime_time(run, lambda: m.eval(q64)) for _ in range(PASSES[run.quick]))
        rows.append({"what": f"{name}.eval", "us/call at 1": one, "us/call at 64": many,
                     "fixed us": min(max(one - (many - one) / 63, 0.0), one)})
    q = queries(materials["ggx"] if "ggx" in materials else next(iter(materials.values())), 1, run.seed)
    rows.append({"what": "Query(wi, wo) (checked)", "us/call at 1": 1e6 * run.time(lambda: Query(q.wi, q.wo)),
                 "us/call at 64": None, "fixed us": None})
    run.table("fixed", "Fixed cost of a call (one thread)", rows,
              "target (issue 49): <= 50 us fixed cost per eval call, so that batches of 64 cost little more; "
              "'fixed us' = the call at 1 less one query's work, (at 64 - at 1) / 63 (within [0, at 1]); each time "
              f"the best of {PASSES[run.quick]} timing(s)")


def _materials(run: harness.Run) -> dict:
    """Analytic GGX, every registered model at its default config in runtime form, and a measured RGL table."""
    out = {"ggx:roughness=0.2": open_material("ggx:roughness=0.2")}
    names = QUICK_MODELS if run.quick else load_all().names()
    if run.quick:
        run.skip(f"models other than {', '.join(QUICK_MODELS)}", "--quick")
    for name in names:
        out[name] = runtime_model(name, run.seed)
    data = shared_data_dir()
    if data is None:
        run.skip("measured reference", "shared data absent (neumat.io.shared_data)")
    else:
        out["rgl:paper_white"] = open_material(data / RGL_FILE)
    return out


def runtime_model(name: str, seed: int, **config):
    """Registered model `name` at its default (paper) config changed by `config`, seeded, in its runtime form and
    eval mode."""
    torch.manual_seed(seed)
    model = load_all().get(name)(**config)
    if name == "sparse-btf":  # a default SparseBTF holds no codes nor directions: UBO2014's 151 directions, and
        g = torch.Generator().manual_seed(seed)  # every data point its full budget tau of random coefficients
        c = model.cfg
        with torch.no_grad():
            model.light_dirs.copy_(direction_set("ubo151"))
            model.view_dirs.copy_(direction_set("ubo151"))
            for ch, tau in enumerate(c.tau):
                model.counts[ch] = tau
                model.values[ch, :, :tau] = torch.randn(model.values.shape[1], tau, generator=g)
                for mode, size in enumerate((c.patch, c.patch, c.n_light, c.n_view)):
                    model.index[ch, :, :tau, mode] = torch.randint(size, (model.index.shape[1], tau), generator=g,
                                                                   dtype=torch.int32)
    if name == "pca-btf":  # a default PCABTF holds no components: those that fit SparseBTF's bytes for this size
        g = torch.Generator().manual_seed(seed)  # (15, split as a least-error split of a measured BTF would,
        c = model.cfg                            # mostly luminance), random, and UBO2014's directions
        with torch.no_grad():
            model.set_ranks((9, 3, 3))
            model.light_dirs.copy_(direction_set("ubo151"))
            model.view_dirs.copy_(direction_set("ubo151"))
            for ch, r in enumerate(model.cfg.ranks):
                model.basis[ch, :, :r] = torch.randn(c.n_light * c.n_view, r, generator=g) / c.n_light
                model.coeffs[ch, :, :r] = torch.randn(c.height * c.width, r, generator=g)
    if name == "dipole-bssrdf":
        k = model.cfg.samples  # its surface quadrature, set from the object in training: a sphere of radius 0.5
        x = 0.5 * sample_uniform_sphere(torch.rand(k, 2))
        model.set_surface(x, 2 * x, torch.full((k,), torch.pi / k))
    return model.runtime().eval()


def queries(material, n: int, seed: int = 0) -> Query:
    """n queries on the material's domain: cosine-weighted hemisphere pairs (the sphere for translucent
    models), uv and x where it reads them."""
    g = torch.Generator().manual_seed(seed)
    u = torch.rand(n, 6, generator=g)
    if material.full_sphere:
        x = 0.5 * sample_uniform_sphere(u[:, 4:6])
        return Query(sample_uniform_sphere(u[:, :2]), sample_uniform_sphere(u[:, 2:4]), x=x, n=2 * x)
    uv = u[:, 4:6] if material.spatially_varying else None
    return Query(sample_cosine_hemisphere(u[:, :2]), sample_cosine_hemisphere(u[:, 2:4]), uv=uv)


def _eval_rate(run: harness.Run, material, n: int) -> float:
    q = queries(material, n, run.seed)
    return n / _runtime_time(run, lambda: material.eval(q))


def _runtime_time(run: harness.Run, fn) -> float:
    """run.time(fn) with autograd off, as a renderer calls a shipped model (neumat.render and the Mitsuba
    integrations evaluate under torch.no_grad; models keep what they derive from their parameters only then)."""
    def call():
        with torch.no_grad():
            fn()
    return run.time(call)


def _sample_rate(run: harness.Run, material, n: int) -> float:
    q = queries(material, n, run.seed)
    u = torch.rand(n, 2, generator=torch.Generator().manual_seed(run.seed + 1))

    def sample_and_pdf():
        s = material.sample(q, u)
        material.pdf(replace(q, wo=s.wo))
    return n / _runtime_time(run, sample_and_pdf)


def _exports(run: harness.Run, materials: dict, n: int, runtime_rates: dict, paths: dict, sgemm: float) -> None:
    """GLSL on llvmpipe (EGL) at both precisions and Slang on slangpy's CPU device, each beside GGX and the
    harness's floor (a shader returning wi + wo) in the same target, where the package exports the model:
    marginal rates per wall and
    per CPU second of this process (llvmpipe's thread included), % of the sgemm bound, cost against GLSL GGX and
    against the model's own runtime (torch or C kernel) per CPU second."""
    from neumat.export.glsl_common import GLSL_VERSION, GLSLExport
    from neumat.export.registry import load_formats
    from neumat.export.slang import slang_from_glsl
    from neumat.testing.drjit_parity import drjit_available, drjit_evals_per_second, mitsuba_measured_evals_per_second
    from neumat.testing.glsl_ggx import ggx_glsl
    from neumat.testing.parity import glsl_evals_per_second, opengl_available
    from neumat.testing.slang_parity import slang_available, slang_evals_per_second

    targets = {"glsl (llvmpipe)": (opengl_available("egl"), glsl_evals_per_second,
                                   ("fp32",) if run.quick else ("fp32", "fp16")),
               "slang (slangpy cpu)": (slang_available("cpu"), slang_evals_per_second, ("fp16",)),
               "drjit (llvm)": (drjit_available(), _one_thread(drjit_evals_per_second), ("fp32",))}
    names = ["neubrdf"] if run.quick else [k for k in materials if k in load_all().names()]
    if run.quick:
        run.skip("exports of models other than neubrdf", "--quick")
    rows, torch_rates = [], {}
    for target, (available, rate, precisions) in targets.items():
        fmt = target.split()[0]
        if not available:
            run.skip(f"{fmt} export rates", f"{target} is not available on this machine")
            continue
        jobs = []
        if fmt in ("glsl", "slang"):  # GGX and the harness's floor in the same target, from their GLSL
            ggx = materials["ggx:roughness=0.2"]
            floor = GLSLExport("// harness floor\nvec3 neumat_eval(vec3 wi, vec3 wo) { return wi + wo; }", {}, False)
            spell = (lambda g, name: g) if fmt == "glsl" else slang_from_glsl
            jobs += [("ggx:roughness=0.2", "fp32", spell(ggx_glsl(ggx), "ggx"), ggx, target, rate),
                     ("harness floor (wi + wo)", "fp32", spell(floor, "floor"), ggx, target, rate)]
        for name in names:
            if run.quick and fmt == "slang":  # its C++ compile of NeuBRDF alone took 20 of the quick run's 45 s
                run.skip(f"slang export of {name}", "--quick (the full run times it)")
                continue
            m = materials[name]
            for precision in precisions:
                try:
                    exported = load_formats().get(fmt).export(m, precision=precision)
                except Exception as e:  # noqa: BLE001  (a model without this export: recorded, not fatal)
                    run.skip(f"{fmt} export of {name}", f"{type(e).__name__}: {str(e).splitlines()[0][:120]}")
                    continue
                jobs.append((name, precision, exported, m, target, rate))
                if fmt == "glsl" and exported.images:  # its textures as images (4.20); also as samplers (3.30)
                    jobs.append((name, precision, exported, m, "glsl 3.30 (llvmpipe)",
                                 functools.partial(rate, version=GLSL_VERSION)))
        ggx_rate = None
        for name, _, _, m, _, _ in jobs:  # the runtime's torch operations too, where a fused C kernel is its path
            if name in names and name not in torch_rates and paths.get(name) == "C kernel":
                with cpu_kernels.switched_off():
                    torch_rates[name] = _eval_rate(run, m, n)
        for name, precision, exported, m, label, measure in jobs:
            run.progress(f"{label}: {name} ({precision})")
            q = queries(m, n, run.seed)
            both = measure(exported, q, clock="both", repeats=run.repeats if run.quick else max(run.repeats, 5))
            wall, cpu = both["wall"], both["cpu"]
            flops = int(m.flops()) if name in names and callable(getattr(m, "flops", None)) else None
            if name == "ggx:roughness=0.2":
                ggx_rate = cpu
            rows.append({"material": name, "target": label, "precision": precision, "queries": n,
                         "evals/wall s": wall, "evals/cpu s": cpu,
                         "% sgemm": None if flops is None else 100 * flops * cpu / sgemm,
                         "x GGX": None if ggx_rate is None or name.startswith("harness") else ggx_rate / cpu,
                         "x runtime": runtime_rates[name] / cpu if name in runtime_rates else None,
                         "x torch ops": None if name not in torch_rates else torch_rates[name] / cpu})
    rgl = materials.get("rgl:paper_white")
    if rgl is not None and targets["drjit (llvm)"][0]:  # the measured reference against Mitsuba's own plugin
        run.progress("mitsuba measured (llvm): rgl:paper_white")
        both = _one_thread(mitsuba_measured_evals_per_second)(shared_data_dir() / RGL_FILE, queries(rgl, n,
                                                                                                  run.seed),
                                                              clock="both", repeats=max(run.repeats, 5))
        rows.append({"material": "rgl:paper_white", "target": "mitsuba measured (llvm)", "precision": "fp32",
                     "queries": n, "evals/wall s": both["wall"], "evals/cpu s": both["cpu"], "% sgemm": None,
                     "x GGX": None, "x runtime": runtime_rates["rgl:paper_white"] / both["cpu"]
                     if "rgl:paper_white" in runtime_rates else None, "x torch ops": None})
    run.table("exports", "Export targets (one thread where the target honours it)", rows,
              "marginal rates between n/8 and n queries (neumat.testing.parity.marginal_rate: start-up, "
              "compilation and uploads do not count), per wall second and per CPU second of this process, both "
              "read around the same calls (best of the run's repeats, at least 5 in a full run; llvmpipe's thread "
              "counted in CPU seconds, a loaded machine's waits not); llvmpipe with LP_NUM_THREADS = the run's "
              "threads; 'glsl (llvmpipe)' compiles each export under its fastest GLSL (4.20 where it reads textures "
              "as images), 'glsl 3.30' under the GLSL 3.30 every export runs under (those textures through "
              "samplers); "
              "'% sgemm' from the CPU rate and the model's "
              "FLOPs; 'x GGX' = GGX's CPU rate in the same target and harness / the row's; 'x runtime' = the "
              "package's own runtime (its torch operations or fused C kernel: the 'path' above) at the same batch, "
              "evals/cpu s / the row's; 'x torch ops' the same against the runtime's torch operations where its "
              "path is a C kernel (the kernels switched off); the floor row is the harness's "
              "own cost (query upload, one fragment, read-back); the 'mitsuba measured' row is Mitsuba 3's own `measured` "
              "plugin on the same RGL file in the Dr.Jit harness (its eval is BRDF x cos), its 'x runtime' neumat's "
              "RGL reader's rate over Mitsuba's (below 1: neumat's is slower)")


def _one_thread(rate):
    """`rate` with Dr.Jit on one thread (the suite's single-thread protocol), its thread count restored after; the
    harness's clock / repeats arguments pass through where `rate` takes them."""
    import inspect

    takes = set(inspect.signature(rate).parameters)

    def wrapped(exported, q, **kwargs):
        from neumat.core.mitsuba import mitsuba_threads

        with mitsuba_threads(1):
            return rate(exported, q, **{k: v for k, v in kwargs.items() if k in takes})
    return wrapped


def _training(run: harness.Run) -> None:
    """CPU seconds per training step per phase (median over the phase's steps after its first) at two batches; the
    texture-set models also on the whole 1K set beside a crop of it, with the ratio (issue 49: a step on a 1K set
    within 3x of the same step on a 64^2 crop)."""
    batches = [2 ** 8, 2 ** 10] if run.quick else [2 ** 10, 2 ** 13]
    crop, whole = (32, 64) if run.quick else (64, None)  # texels of the crop and of the "whole" set (None: 1K)
    svbrdf = shared_data_dir()
    if run.quick:
        jobs = [("nbrdf", {}, DEFAULT_PRESET), ("neubrdf", {"nside": 8}, DEFAULT_PRESET),
                ("multiscale", {}, DEFAULT_PRESET)]
        run.skip("training steps of models other than nbrdf, neubrdf (N_side 8) and multiscale (crops of 32^2 and "
                 "64^2 instead of 64^2 and the whole 1K set; no paper-recipe row)", "--quick")
    else:
        jobs = [(n, {}, DEFAULT_PRESET) for n in load_all().names()
                if load_all().get(n).source_kinds[0] in ("brdf", "svbrdf") and n != "ggx"]
        jobs.append(("multiscale", {}, "cpu"))  # the paper's recipe (its spatial preconditioner's FFTs) beside it
        for n in load_all().names():
            if load_all().get(n).source_kinds[0] not in ("brdf", "svbrdf"):
                run.skip(f"training steps of {n}", f"source kind {load_all().get(n).source_kinds[0]!r} not timed")
    rows = []
    for name, overrides, preset in jobs:
        run.progress(f"training steps of {name} ({preset})")
        kind = load_all().get(name).source_kinds[0]
        if kind == "svbrdf" and svbrdf is None:
            run.skip(f"training steps of {name}", "no SVBRDF texture set: shared data absent")
            continue
        if kind == "brdf":
            sizes = [(None, open_material("ggx:roughness=0.2"), batches)]
        else:
            folder = svbrdf / "svbrdf" / "Wood092_1K"
            whole_set = open_material(folder) if whole is None else open_material(folder, crop=whole)
            sizes = [(crop, open_material(folder, crop=crop), batches),
                     (whole_set.textures.size[0], whole_set, batches[-1:])]
        at_crop = {}
        for texels, source, size_batches in sizes:
            for batch in size_batches:
                for phase, seconds in step_seconds(name, preset, overrides, source, batch, 3 if run.quick else 10,
                                                   run.seed):
                    if texels == crop:
                        at_crop[(batch, phase)] = seconds
                    ratio = at_crop.get((batch, phase)) if texels not in (None, crop) else None
                    rows.append({"model": name, "preset": preset, "texels": None if texels is None else f"{texels}^2",
                                 "batch": batch, "phase": phase, "cpu s/step": seconds,
                                 f"x {crop}^2": None if ratio is None else seconds / ratio})
    run.table("training", "Training step CPU time per phase (library trainer, CPU recipe)", rows,
              f"median over each phase's steps after its first; each model at its default preset ({DEFAULT_PRESET!r}: "
              "what `neumat fit` runs), multiscale also at 'cpu' (the paper's model and recipe, with its spatial "
              "preconditioner); sources: analytic GGX (BRDF models), Wood092_1K "
              f"cropped to {crop}^2 and " + ("a 64^2 crop" if run.quick else "whole (1024^2)") +
              f" (SVBRDF models; 'x {crop}^2' = the step over the same step on the crop)" +
              ("; quick: neubrdf at N_side 8" if run.quick else ""))


def step_seconds(name: str, preset: str, overrides: dict, source, batch: int, per_phase: int,
                 seed: int) -> list[tuple]:
    """[(phase, median CPU seconds per step)] of a fit of `name` through `neumat.fit.trainer.fit` at `preset` on the
    CPU recipe with `batch`, long enough that every phase of the recipe gets about `per_phase` steps or more. A step is timed
    from the start of one (the trainer's `model.on_step` call) to the start of the next, with no history record or
    rollback snapshot between them (a snapshot copies the model and its optimiser state: on a 1K latent texture a
    good share of a step)."""
    model, setting = build_fit(name, preset, source=source, overrides=overrides, seed=seed)
    recipe = setting.recipe
    fractions = [f for f in (_phase_fractions(recipe) or [1.0]) if f > 0]
    steps = int(per_phase / min(fractions)) + 1
    starts: list[tuple[int, float]] = []
    on_step = model.on_step

    def timed(step: int, total: int) -> None:
        starts.append((step, time.process_time()))
        on_step(step, total)

    model.on_step = timed
    with warnings.catch_warnings():  # a few dozen steps are timed, not judged: their loss curve means nothing
        warnings.simplefilter("ignore", FitWarning)
        history = fit(model, source, replace(recipe, batch_size=batch, steps=steps, log_every=10 ** 9,
                                              checkpoint_every=10 ** 9), progress=False).history
    ends = [(r["step"], r["phase"]) for r in history]  # one record at the end of each phase

    def phase_of(step: int) -> tuple[int, str]:
        return next((end, phase) for end, phase in ends if step < end)

    per_phase_times: dict[str, list[float]] = {}
    for (s0, t0), (s1, t1) in zip(starts, starts[1:]):
        end, phase = phase_of(s0)
        first = s0 == 0 or phase_of(s0 - 1)[0] != end  # a phase's first step: warm-up, not timed
        if s1 == s0 + 1 < end and not first:
            per_phase_times.setdefault(phase, []).append(t1 - t0)
    return [(p, statistics.median(ts)) for p, ts in per_phase_times.items()]


def _phase_fractions(recipe) -> list[float]:
    """The recipe's phase fractions: its phase_split, or NeuBRDF's option fractions (coarse, dense warm-up)."""
    if recipe.phase_split:
        return list(recipe.phase_split)
    o = recipe.options
    bounds = sorted(f for f in (o.get("coarse_fraction", 0), o.get("dense_warmup", 0)) if 0 < f < 1)
    return [b - a for a, b in zip([0.0] + bounds, bounds + [1.0])]
