"""SparseBTF benchmark: quality vs coefficients, storage, PCA at equal storage, training / coding time and
reconstruction throughput (CPU, CUDA when available, the exported GLSL when an OpenGL 3.3 context can be made),
coefficient- vs value-space interpolation.

    python benchmarks/studies/btf/btf.py                       # procedural texture sets (no data needed)
    python benchmarks/studies/btf/btf.py --size 40 --dirs rings:3x30 --patch 10 --dictionaries 4 --iterations 10
    python benchmarks/studies/btf/btf.py --size 120 --test shared --shared-relief 4
                                                   # test on BTFs generated from the six real PBR sets
    python benchmarks/studies/btf/btf.py --render              # also renders a BTF-textured plane and bunny (comparison PNGs)
    python benchmarks/studies/btf/btf.py --train-seeds 6 --train-shared ../shared/data/svbrdf --tiles 2 --dictionaries 8
                                                   # a larger training set (benchmarks/studies/btf/results/btf_vs_pca.md)
    python benchmarks/studies/btf/btf.py --size 120 --dictionaries 8 --train-variants 3 \
        --test bricks,dents,ridges,bumps~9,weave~9     # the paper's protocol: training covers the classes
                                                   # (benchmarks/studies/btf/results/btf_vs_pca.md, section 11)
    python benchmarks/studies/btf/btf.py --neubrdf             # also NeuBRDF with a neural texture at SparseBTF's bytes
    python -u benchmarks/studies/btf/btf.py --dirs ubo151 --size 100 --train-size 20 --tau-train 256,32,32 --dictionaries 8 \
        --iterations 3 --train-seeds 6 --train-shared ../shared/data/svbrdf --shared-relief 4 \
        --save-dictionary d151.nmat            # the paper's Table 5 regime; trains on 264 data points (bumps
                                               # and weave at --size, 16 BTFs at --train-size), about 10 min per
                                               # channel on 2 cores; later runs: --dictionary d151.nmat

Training set: --train (with --train-seeds S also their procedural layouts from seeds 2..S, with
--train-variants N also variants 1..N of every procedural class, with --train-shared also tiles of real PBR
sets); test set: --test, never seen in training (refused otherwise). Procedural test materials are a class
('bricks', its canonical material) or another material of the class ('bricks~7', see
`neumat.reflectance.procedural_texture`).
MSE is reported on linear RGB (the BTF values) and in the log-YUV space the models code (log(x + eps), before
the per-image standardisation). PCA gets the same per-BTF bytes as SparseBTF's codes plus statistics, and is
charged for its bases and means ("PCA"); "PCA paper" is charged only its per-texel coefficients, as the
compression ratios of the paper's Table 5 imply (PCA (64) at half of SparseBTF (32)'s 2122: 22801 x 3 / 64).
Both PCAs split their components over Y, U, V to minimise the log-YUV error (`pca_btf.best_ranks`) of one
`pca_btf.decompose` per test BTF ("PCA decomposition s"). Test BTFs are generated one at a time.
After the shared dictionary is trained (or loaded), every test BTF is one job (`code_test_btf`): one after
another in this process, or with `--engine ray` as Ray tasks (`neumat.cli.fit_engines`, as `neumat fit-many`)
on a local instance (`--workers N`) or a cluster (`--address` / $RAY_ADDRESS). A test BTF that fails is left
out of the tables and named above them; the others finish.
--oracle adds "oracle sparse MSE" / "oracle sparse log MSE": the test BTF coded with a dictionary trained on
itself alone, a bound on what a better training set could give. "coding s (all rates)" codes a test BTF at
every --mults rate with one projection of its data points (`SparseBTF.encode_rates`). "statistics share" is
the part of SparseBTF's per-BTF bytes taken by its per-image means and deviations: float32 as in the authors'
files, or float16 with --statistics-bytes 2; --statistics btf codes with one mean and deviation per channel
instead (SparseBTF Config.statistics) (rounding them, the values and the dictionaries to float16 changed
the MSEs of bricks, dents and ridges by at most 0.1% at the default sizes; a test checks it on synthetic BTFs).

--neubrdf: for every test BTF and tau row, a NeuBRDF with its neural-texture plug-in (texture at the BTF's
resolution, one latent vector per texel) whose fp16 size_bytes() is closest to SparseBTF's per-BTF bytes (the
texture channels take the budget; grid and MLP fixed by --neubrdf-nside / --neubrdf-hidden), fitted with the
NeuBRDF recipe (Adam 1e-2 halved every quarter of --neubrdf-steps, EMA; loss log_cos, or each loss of
--neubrdf-loss) to exactly the BTF's table entries (every texel centre x every (light, view) pair, replayed),
then decoded over the same entries and scored with the same MSEs. "constant floor" is the smallest MSE any
constant-over-space model (a NeuBRDF without texture included) can reach on the table: in linear RGB that of
the per-(light, view) spatial mean, in log-YUV the spatial variance of the log-YUV values.
"""
from __future__ import annotations

import argparse
import math
import os
import socket
import time
from dataclasses import replace
from pathlib import Path

import torch
from rich.console import Console

from neumat.cli.common import print_table
from neumat.cli.fit_engines import RunProgress, add_engine_arguments, run_jobs
from neumat.core.errors import InputError
from neumat.core.query import Query
from neumat.export.glsl import export_glsl
from neumat.fit.method import recipe_for
from neumat.fit.trainer import fit
from neumat.io.shared_data import shared_data_dir
from neumat.io.texture_set import load_texture_set
from neumat.color.tonemap import LUMINANCE
from neumat.fit.measured_samples import table_samples
from neumat.models.btf_table_queries import decode_table
from neumat.methods.neubrdf.model import NeuBRDF
from neumat.methods.sparse_btf.pca_solve import best_ranks, decompose, fit_pca
from neumat.methods.sparse_btf.pca import rank_budget
from neumat.methods.sparse_btf.model import SparseBTF, mse
from neumat.methods.sparse_btf.dictionary_train import train_dictionary
from neumat.methods.sparse_btf.dictionary import BTFDictionary, rgb_to_model_space
from neumat.reflectance.btf import direction_set
from neumat.reflectance.btf_generate import generate_btf, texture_tile
from neumat.reflectance.procedural_texture import KINDS, RELIEF, material_name, parse_material, procedural_texture_set
from neumat.testing.parity import glsl_evals_per_second, opengl_available


def table(title, rows):
    """A results table, wide enough for the logs the benchmark is run into."""
    print_table(title, rows, width=320)


def material_names(spec: str, shared: str) -> list[str]:
    """Names in a comma-separated `spec`: procedural materials (a class, or 'class~variant'), texture-set
    folders under `shared`, or `shared` for all of them."""
    folders = sorted(p.name for p in Path(shared).iterdir() if p.is_dir()) if shared and Path(shared).is_dir() else []
    names = []
    for token in filter(None, spec.split(",")):
        if token == "shared":
            if not folders:
                raise SystemExit(f"'shared' in {spec!r}: no texture sets under --shared {shared!r}")
            names += folders
        elif is_procedural(token) or token in folders:
            names.append(token)
        else:
            raise SystemExit(f"unknown material {token!r}: expected one of {KINDS} (optionally ~<variant>), "
                             f"'shared', or a texture-set folder under --shared ({shared!r})")
    return names


def is_procedural(name: str) -> bool:
    """Whether `name` is a procedural material ('class' or 'class~variant')."""
    try:
        parse_material(name)
    except InputError:
        return False
    return True


def procedural_btf(name: str, size: int, seed: int, args, dirs):
    """The BTF of procedural material `name` ('class' or 'class~variant'; layout seed, size x size texels, relief
    4 x --relief)."""
    kind, variant = parse_material(name)
    return generate_btf(procedural_texture_set(kind, size, seed=seed, variant=variant), dirs, dirs,
                        relief=args.relief * RELIEF, spp=args.spp)


def texture_set_btf(ts, size: int, crop: int, at: int, args, dirs):
    """The BTF of the crop x crop tile of texture set `ts` at row = column = `at`, resampled to size x size
    texels, relief x --shared-relief."""
    tile, relief = texture_tile(ts, size, crop=crop, row=at, col=at)
    return generate_btf(tile, dirs, dirs, relief=relief * args.shared_relief, spp=args.spp)


def generate_material(name: str, args, dirs, tile_index: int = 0):
    """The BTF of a procedural kind (seed 1) or of a texture set under --shared (a --crop tile at row = column =
    --crop-at + tile_index x crop, wrapped into the image), at --size texels."""
    if is_procedural(name):
        return procedural_btf(name, args.size, 1, args, dirs)
    ts = load_texture_set(Path(args.shared) / name)
    crop = min(args.crop or args.size, *ts.size)
    return texture_set_btf(ts, args.size, crop, (args.crop_at + tile_index * crop) % (min(ts.size) - crop + 1),
                           args, dirs)


def extra_training_btfs(args, dirs, kinds: list[str], test: list[str]) -> dict:
    """More training BTFs (args.train_size texels, default args.size): the procedural `kinds` with seeds
    2..args.train_seeds, variants 1..args.train_variants of the procedural classes args.variant_classes (other
    materials of the class, layout seed 1) except those in `test`, tiles 1..args.train_tiles - 1 of the texture sets in
    `kinds`, and args.tiles tiles of every PBR set in args.train_shared (256-texel crops; relief x
    args.shared_relief). Test materials stay unseen."""
    out, size = {}, args.train_size or args.size
    for variant in range(1, args.train_variants + 1):
        for name in (material_name(k, variant) for k in args.variant_classes.split(",")):
            if name not in test:
                out[name] = procedural_btf(name, size, 1, args, dirs)
    for seed in range(2, args.train_seeds + 1):
        for k in (k for k in kinds if is_procedural(k)):
            out[f"{k}#{seed}"] = procedural_btf(k, size, seed, args, dirs)
    for i in range(1, args.train_tiles):
        for k in (k for k in kinds if not is_procedural(k)):
            out[f"{k}#{i}"] = generate_material(k, args, dirs, tile_index=i)
    for folder in sorted(Path(args.train_shared).iterdir()) if args.train_shared else []:
        ts = load_texture_set(folder)
        crop = min(256, *ts.size)
        for i in range(args.tiles):
            out[f"{ts.name}#{i}"] = texture_set_btf(ts, size, crop, i * crop % max(1, min(ts.size) - crop + 1),
                                                    args, dirs)
    return out


def train_on_materials(train: list[str], test: list[str], args, dirs, tau_l: tuple[int, int, int]
                       ) -> BTFDictionary:
    """Generate the training BTFs (materials `train` plus the extra ones), train the dictionary, print its cost."""
    t = time.perf_counter()
    btfs = {name: generate_material(name, args, dirs) for name in train}
    extra = extra_training_btfs(args, dirs, train, test)
    btfs.update(extra)
    train = train + list(extra)
    gen_s = time.perf_counter() - t
    t = time.perf_counter()
    dic = train_dictionary([btfs[k] for k in train], args.dictionaries, tau_l, args.patch, max_iters=args.iterations,
                           sample_fraction=args.sample_fraction, progress=True, statistics=args.statistics)
    train_s = time.perf_counter() - t
    print(f"{len(train)} training BTFs ({args.train_size or args.size}x{args.train_size or args.size} texels) x "
          f"{dirs.shape[0]}x{dirs.shape[0]} directions generated in {gen_s:.1f} s; dictionary (K={args.dictionaries}, "
          f"tau_l={tau_l}, patch {args.patch}) trained on {train} ({dic.info['points']} data points per channel) in "
          f"{train_s:.1f} s ({torch.get_num_threads()} threads; the paper: 101 h on 128 cores); iterations "
          f"{dic.info['iterations']}")
    return dic


def win_summary(rows: list[dict], mults: list[int], taus: dict) -> list[dict]:
    """Per tau multiplier: how many test BTFs SparseBTF beats PCA (equal bytes) on, and the mean error ratios."""
    out = []
    for mult in mults:
        mine = [r for r in rows if r["tau_t (Y,U,V)"] == str(taus[mult])]
        lin = [r["PCA MSE"] / r["sparse MSE"] for r in mine]
        log = [r["PCA log MSE"] / r["sparse log MSE"] for r in mine]
        both = sum(a > 1 and b > 1 for a, b in zip(lin, log))
        neither = sum(a <= 1 and b <= 1 for a, b in zip(lin, log))
        out.append({"tau x": mult, "tau_t (Y,U,V)": str(taus[mult]), "BTFs": len(mine), "wins (both spaces)": both,
                    "split": len(mine) - both - neither, "losses (both spaces)": neither,
                    "PCA / sparse MSE (geo. mean)": math.exp(sum(map(math.log, lin)) / len(lin)),
                    "PCA / sparse log MSE (geo. mean)": math.exp(sum(map(math.log, log)) / len(log))})
    return out


def log_mse(reference, test, eps: float) -> float:
    """MSE in log-YUV (the models' space before standardisation)."""
    a = rgb_to_model_space(reference.data, eps)
    return float(((a - rgb_to_model_space(test.data.to(reference.data), eps)) ** 2).mean())


def constant_floor(btf, eps: float) -> tuple[float, float]:
    """Smallest MSE any constant-over-space model can reach on the table, in linear RGB (that of the
    per-(light, view) spatial mean) and in log-YUV (the spatial variance of the log-YUV values)."""
    linear = float(((btf.data - btf.data.mean(dim=(2, 3), keepdim=True)) ** 2).mean())
    yuv = rgb_to_model_space(btf.data, eps)
    return linear, float(((yuv - yuv.mean(dim=(2, 3), keepdim=True)) ** 2).mean())


def neubrdf_for_bytes(budget: int, height: int, width: int, nside: int, hidden: int) -> NeuBRDF:
    """A NeuBRDF (vq grid N_side `nside`, k 8, b 6, MLP 2 x `hidden`) with a height x width neural texture whose
    channel count makes its fp16 size_bytes() closest to `budget` (at least one channel)."""
    def make(c: int) -> NeuBRDF:
        return NeuBRDF(nside=nside, feature_dim=8, index_bits=6, hidden=hidden, texture_height=height,
                       texture_width=width, texture_channels=c)

    c = 1
    while make(c + 1).size_bytes() <= budget:
        c += 1
    if abs(make(c + 1).size_bytes() - budget) < abs(make(c).size_bytes() - budget):
        c += 1
    return make(c)


def fit_neubrdf(btf, budget: int, loss: str, args) -> tuple[NeuBRDF, float]:
    """NeuBRDF with a neural texture at ~`budget` bytes fitted with `loss` to the table entries of `btf`;
    (model, seconds)."""
    h, w = btf.shape[2:]
    torch.manual_seed(0)
    model = neubrdf_for_bytes(budget, h, w, args.neubrdf_nside, args.neubrdf_hidden)
    recipe = replace(recipe_for("neubrdf"), steps=args.neubrdf_steps, batch_size=args.neubrdf_batch,
                     lr_decay_every=max(1, args.neubrdf_steps // 4), loss=loss)
    result = fit(model, table_samples(btf), recipe, queries="replay", progress=False)
    return model, result.seconds


def neubrdf_rows(name: str, btf, mults: list[int], rows_by: dict, log_eps: float, args) -> list[dict]:
    """NeuBRDF with a neural texture at SparseBTF's per-BTF bytes for every tau row of one test BTF."""
    out = []
    floor, floor_log = constant_floor(btf, log_eps)
    for mult, loss in ((m, l) for m in mults for l in args.neubrdf_loss.split(",")):
        sp_row = rows_by[(name, mult)]
        try:
            model, seconds = fit_neubrdf(btf, sp_row["per-BTF bytes"], loss, args)
        except InputError as e:                         # a non-finite loss: say so, go on
            print(f"NeuBRDF fit of {name} (tau x{mult}, {loss}) failed: {e}")
            continue
        decoded = decode_table(model, btf)
        c = model.cfg
        out.append({"btf": name, "tau x": mult, "loss": loss, "sparse bytes": sp_row["per-BTF bytes"],
                    "NeuBRDF bytes": model.size_bytes(),
                    "texture h x w x c": f"{c.texture_height}x{c.texture_width}x{c.texture_channels}",
                    "NeuBRDF MSE": mse(btf, decoded), "sparse MSE": sp_row["sparse MSE"],
                    "PCA MSE": sp_row["PCA MSE"], "constant floor MSE": floor,
                    "NeuBRDF log MSE": log_mse(btf, decoded, log_eps),
                    "sparse log MSE": sp_row["sparse log MSE"], "PCA log MSE": sp_row["PCA log MSE"],
                    "constant floor log MSE": floor_log, "fit s": seconds})
    return out


def shared_file(relative: str) -> Path:
    """A file of the shared reference data (`neumat.io.shared_data`); exits with a message when it is absent."""
    data = shared_data_dir()
    path = data / relative if data is not None else None
    if path is None or not path.is_file():
        raise SystemExit(f"--render needs shared/data/{relative} (set NEUMAT_SHARED_DATA or put shared/ beside the "
                         "checkout)")
    return path


def bunny_with_uv(path: Path) -> Path:
    """The 453-vertex Stanford bunny with spherical texture coordinates (the shared mesh has none), as PLY."""
    from neumat.core.mitsuba import import_mitsuba
    mi = import_mitsuba()
    src = mi.load_dict({"type": "ply", "filename": str(shared_file("mesh/stanford_bunny_res4_453v.ply"))})
    params = mi.traverse(src)
    pos = torch.tensor(list(params["vertex_positions"])).reshape(-1, 3)
    faces = list(params["faces"])
    d = torch.nn.functional.normalize(pos - pos.mean(0), dim=-1)
    uv = torch.stack([(torch.atan2(d[:, 0], d[:, 2]) / (2 * math.pi)) % 1.0, torch.acos(d[:, 1]) / math.pi], -1)
    uv = uv * 4                                             # four repeats around the bunny
    mesh = mi.Mesh("bunny_uv", pos.shape[0], len(faces) // 3, has_vertex_texcoords=True)
    p = mi.traverse(mesh)
    p["vertex_positions"] = mi.Float(pos.reshape(-1).tolist())
    p["vertex_texcoords"] = mi.Float(uv.reshape(-1).tolist())
    p["faces"] = mi.UInt32(faces)
    p.update()
    mesh.write_ply(str(path))
    return path


def render_figures(models: dict, out: Path, spp: int, resolution: int) -> list[dict]:
    """Render every model on a plane and the bunny under an environment map; writes `btf_<scene>_compare.png`
    (reference | model | FLIP error map, a row per model) into `out`, at the exposure that puts the reference's
    99th-percentile luminance at 0.9 (the metrics use the same exposure)."""
    from neumat.io.images import write_image_ldr
    from neumat.metrics.image import image_metrics
    from neumat.render.render import render
    from neumat.viz.compare import compare_image

    out.mkdir(parents=True, exist_ok=True)
    env = f"env:{shared_file('envmap/studio_small_03_1k.hdr')}"
    import tempfile
    bunny = bunny_with_uv(Path(tempfile.mkdtemp()) / "bunny_uv.ply")
    scenes = {"plane": "plane,uv_scale=2", "bunny": f"mesh:{bunny},zoom=1.3"}
    rows = []
    for scene_name, scene in scenes.items():
        images, seconds = {}, {}
        for name, model in models.items():
            t = time.perf_counter()
            images[name] = render(model, scene=scene, light=env, spp=spp, resolution=resolution).cpu()
            seconds[name] = time.perf_counter() - t
        ref = images["reference"]
        luminance = ref @ torch.tensor(LUMINANCE)
        exposure = math.log2(0.9 / max(torch.quantile(luminance.flatten(), 0.99).item(), 1e-8))
        metrics = {}
        for name, img in images.items():
            m = image_metrics(ref, img, exposure=exposure) if name != "reference" else {}
            if m:
                metrics[name] = {"PSNR": m["psnr"], "FLIP": m["flip"]}
            rows.append({"scene": scene_name, "model": name, "seconds": seconds[name], "exposure": exposure,
                         "PSNR": m.get("psnr", float("nan")), "FLIP": m.get("flip", float("nan")),
                         "file": f"btf_{scene_name}_compare.png"})
        others = {name: img for name, img in images.items() if name != "reference"}
        write_image_ldr(out / f"btf_{scene_name}_compare.png",
                        compare_image(ref, others, metrics=metrics, exposure=exposure))
    return rows


def speed_queries(n: int) -> Query:
    """n random queries (directions mostly above the horizon, uv in [0, 1))."""
    g = torch.Generator().manual_seed(0)
    wi = torch.nn.functional.normalize(torch.rand(n, 3, generator=g) - torch.tensor([0.5, 0.5, -0.2]), dim=-1)
    wo = torch.nn.functional.normalize(torch.rand(n, 3, generator=g) - torch.tensor([0.5, 0.5, -0.2]), dim=-1)
    return Query(wi, wo, uv=torch.rand(n, 2, generator=g))


def glsl_throughput(model, n: int) -> float:
    """Evaluations per second of the model's GLSL export on the local EGL OpenGL (`glsl_evals_per_second`)."""
    rate = glsl_evals_per_second(export_glsl(model), speed_queries(n))
    if rate != rate:
        print(f"GLSL throughput: {n} queries ran no slower than {n // 8} (overheads dominate); use more --queries")
    return rate


def throughput(model, n, device, reps=3):
    q = speed_queries(n).to(device)
    model.eval(q)
    if device == "cuda":
        torch.cuda.synchronize()
    t = time.perf_counter()
    for _ in range(reps):
        model.eval(q)
    if device == "cuda":
        torch.cuda.synchronize()
    return n * reps / (time.perf_counter() - t)


def code_test_btf(job: dict) -> dict:
    """One test BTF of the benchmark (the shared dictionary trained before): generate it, code it at every rate,
    fit the PCAs (and --oracle / --neubrdf), score them. Its row: {"name", "model", "status" ("ok" or "error"),
    "error", "worker", "seconds", "rows" (the table's, one per rate), "neu_rows", "models" ({mult: SparseBTF}),
    and with job["keep_btf"] "btf_and_decomposition" (for --render)}."""
    t0 = time.perf_counter()
    out = {"name": job["name"], "model": "sparse-btf", "status": "ok", "error": None,
           "worker": f"{socket.gethostname()}:{os.getpid()}"}
    try:
        out.update(score_test_btf(job))
    except Exception as e:  # noqa: BLE001 - one failing test BTF must not stop the tables
        out.update(status="error", error=f"{type(e).__name__}: {e}")
    out["seconds"] = time.perf_counter() - t0
    return out


def lost_test_btf(job: dict, error: BaseException) -> dict:
    """The row of a test BTF whose Ray task was lost (its worker died on every try)."""
    return {"name": job["name"], "model": "sparse-btf", "status": "error", "error": f"{type(error).__name__}: {error}",
            "worker": None, "seconds": 0.0}


def score_test_btf(job: dict) -> dict:
    """The measurements of `code_test_btf` (without the status keys)."""
    name, args, dirs, dic, tau_l, mults = (job[k] for k in ("name", "args", "dirs", "dic", "tau_l", "mults"))
    taus = {m: tuple(t * m for t in tau_l) for m in mults}                 # tau_t per rate
    rows, models, rows_by, neu_rows = [], {}, {}, []
    t = time.perf_counter()
    btf = generate_material(name, args, dirs)
    print(f"test BTF {name} ({args.size}x{args.size} texels) generated in {time.perf_counter() - t:.1f} s")
    t = time.perf_counter()
    coded = dict(zip(mults, SparseBTF.encode_rates(btf, dic, list(taus.values()), statistics=args.statistics)))
    code_s = time.perf_counter() - t
    if args.oracle:
        t = time.perf_counter()
        own = train_dictionary([btf], args.dictionaries, tau_l, args.patch, max_iters=args.iterations,
                               sample_fraction=args.sample_fraction, progress=True, statistics=args.statistics)
        oracle = dict(zip(mults, SparseBTF.encode_rates(btf, own, list(taus.values()), statistics=args.statistics)))
        print(f"oracle dictionary of {name} trained and used in {time.perf_counter() - t:.1f} s")
    budgets = {m: sp.storage(statistics_bytes=args.statistics_bytes)["per_btf"] for m, sp in coded.items()}
    totals = {m: rank_budget(b, dirs.shape[0], dirs.shape[0], args.size, args.size) for m, b in budgets.items()}
    paper_totals = {m: b // (2 * args.size * args.size) for m, b in budgets.items()}   # fp16 per texel
    t = time.perf_counter()
    dec = decompose(btf, dic.log_eps, max(*totals.values(), *paper_totals.values()))
    pca_s = time.perf_counter() - t
    for mult, sp in coded.items():
        st = sp.storage(statistics_bytes=args.statistics_bytes)
        ranks = best_ranks(dec.eigenvalues, totals[mult])
        paper_ranks = best_ranks(dec.eigenvalues, paper_totals[mult])
        pca = fit_pca(btf, ranks, log_eps=dic.log_eps, decomposition=dec)
        pca_paper = fit_pca(btf, paper_ranks, log_eps=dic.log_eps, decomposition=dec)
        decoded, pca_decoded = sp.decode(), pca.decode()
        rows.append({"btf": name, "tau_t (Y,U,V)": str(taus[mult]),
                     "coefficients": st["coefficients"],
                     "sparse MSE": mse(btf, decoded), "PCA ranks": str(ranks),
                     "PCA MSE": mse(btf, pca_decoded),
                     "sparse log MSE": log_mse(btf, decoded, dic.log_eps),
                     "PCA log MSE": log_mse(btf, pca_decoded, dic.log_eps),
                     "PCA paper ranks": str(paper_ranks),
                     "PCA paper MSE": mse(btf, pca_paper.decode()), "per-BTF bytes": st["per_btf"],
                     "statistics share": st["statistics"] / st["per_btf"],
                     "PCA bytes": pca.storage()["total"], "total bytes (+dict)": st["total"],
                     "compression": st["compression_ratio"], "coding s (all rates)": code_s,
                     "PCA decomposition s": pca_s})
        if args.oracle:
            own_decoded = oracle[mult].decode()
            rows[-1] |= {"oracle sparse MSE": mse(btf, own_decoded),
                         "oracle sparse log MSE": log_mse(btf, own_decoded, dic.log_eps)}
            del own_decoded
        del decoded, pca_decoded
        models[mult] = sp
        rows_by[(name, mult)] = rows[-1]
    if args.neubrdf:
        neu_rows = neubrdf_rows(name, btf, mults, rows_by, dic.log_eps, args)
    out = {"rows": rows, "neu_rows": neu_rows, "models": models}
    if job["keep_btf"]:
        out["btf_and_decomposition"] = (btf, dec)
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", type=int, default=40)
    ap.add_argument("--dirs", default="rings:3x30")
    ap.add_argument("--patch", type=int, default=10)
    ap.add_argument("--dictionaries", type=int, default=4)
    ap.add_argument("--iterations", type=int, default=10)
    ap.add_argument("--tau-train", default="32,8,8")
    ap.add_argument("--spp", type=int, default=1)
    ap.add_argument("--relief", type=float, default=1.0)
    ap.add_argument("--queries", type=int, default=1 << 15)
    ap.add_argument("--train", default="bumps,weave", help="training materials (procedural kinds or texture sets)")
    ap.add_argument("--test", default="bricks,dents,ridges",
                    help="test materials, never trained on: procedural kinds, texture-set folders under --shared, "
                         "or 'shared' for all of them")
    ap.add_argument("--shared", default="../shared/data/svbrdf", help="folder of the PBR texture sets")
    ap.add_argument("--crop", type=int, default=0,
                    help="texture-set texels per BTF tile side (default --size: one texture texel per BTF texel)")
    ap.add_argument("--crop-at", type=int, default=300, help="row and column of the texture-set test tiles")
    ap.add_argument("--train-seeds", type=int, default=1,
                    help="also train on the two training kinds generated with seeds 2..S")
    ap.add_argument("--train-variants", type=int, default=0,
                    help="also train on variants 1..N of the --variant-classes (other materials of each class, as "
                         "the paper's training set covers UBO2014's classes); test materials stay unseen")
    ap.add_argument("--variant-classes", default=",".join(KINDS), help="the classes --train-variants draws from")
    ap.add_argument("--train-shared", default="", help="also train on tiles of the PBR sets in this folder")
    ap.add_argument("--train-tiles", type=int, default=1, help="tiles of each texture set named in --train")
    ap.add_argument("--tiles", type=int, default=1, help="tiles per PBR set for --train-shared")
    ap.add_argument("--shared-relief", type=float, default=8.0,
                    help="relief multiplier of texture-set tiles (--test, --train and --train-shared)")
    ap.add_argument("--train-size", type=int, default=0,
                    help="texels of the extra training BTFs (default --size; a dictionary fits any size)")
    ap.add_argument("--sample-fraction", type=float, default=1.0, help="fraction of training data points used")
    ap.add_argument("--dictionary", default="", help="a dictionary saved by --save-dictionary: skip training "
                    "(its training BTFs must not be test materials)")
    ap.add_argument("--save-dictionary", default="", help="write the trained dictionary here")
    ap.add_argument("--mults", default="1,2,4,8,16", help="tau_t = tau_l times these")
    ap.add_argument("--statistics-bytes", type=int, choices=(2, 4), default=4,
                    help="bytes charged per stored per-image mean / std: 4 as the authors' files, 2 (float16)")
    ap.add_argument("--statistics", choices=("image", "btf"), default="image",
                    help="standardisation statistics per angular image (the paper) or per BTF (6 numbers), for "
                         "coding and for training the dictionary")
    ap.add_argument("--oracle", action="store_true",
                    help="also code every test BTF with a dictionary trained on that BTF alone (same K, tau_l, "
                         "iterations): how much of the gap to PCA a better training set could close")
    ap.add_argument("--neubrdf", action="store_true",
                    help="also fit NeuBRDF with a neural texture at SparseBTF's per-BTF bytes (module docstring)")
    ap.add_argument("--neubrdf-steps", type=int, default=1000)
    ap.add_argument("--neubrdf-loss", default="log_cos", help="comma-separated fit losses (neumat.fit.losses)")
    ap.add_argument("--neubrdf-batch", type=int, default=4096)
    ap.add_argument("--neubrdf-nside", type=int, default=4)
    ap.add_argument("--neubrdf-hidden", type=int, default=32)
    add_engine_arguments(ap, "test BTF")
    ap.add_argument("--render", action="store_true", help="render a plane and the bunny (benchmarks/results/)")
    ap.add_argument("--render-spp", type=int, default=16)
    ap.add_argument("--render-size", type=int, default=128)
    args = ap.parse_args()
    dirs = direction_set(int(args.dirs) if args.dirs.isdigit() else args.dirs)
    tau_l = tuple(int(t) for t in args.tau_train.split(","))

    train, test = material_names(args.train, args.shared), material_names(args.test, args.shared)
    if any(k not in KINDS for k in args.variant_classes.split(",")):
        raise SystemExit(f"--variant-classes {args.variant_classes!r}: expected classes among {KINDS}")
    if set(train) & set(test) or (args.train_shared and any(not is_procedural(n) for n in test)):
        raise SystemExit(f"the test materials {test} must not be used in training ({train}"
                         f"{', --train-shared ' + args.train_shared if args.train_shared else ''})")
    if args.dictionary:
        dic = BTFDictionary.load(args.dictionary)
        tau_l = dic.tau_train
        if set(test) & set(dic.info.get("btfs", [])):
            raise SystemExit(f"{args.dictionary} was trained on test materials "
                             f"{sorted(set(test) & set(dic.info['btfs']))}")
        print(f"dictionary {args.dictionary} (K={dic.num_dictionaries}, tau_l={dic.tau_train}, patch {dic.patch}, "
              f"{dic.info.get('points')} data points per channel from {dic.info.get('btfs')}) trained in "
              f"{sum(dic.info.get('seconds', {}).values()):.1f} s; iterations {dic.info.get('iterations')}")
    else:
        dic = train_on_materials(train, test, args, dirs, tau_l)
        if args.save_dictionary:
            print(f"dictionary written to {dic.save(args.save_dictionary)}")

    mults = [int(m) for m in args.mults.split(",")]
    jobs = [{"name": name, "args": args, "dirs": dirs, "dic": dic, "tau_l": tau_l, "mults": mults,
             "keep_btf": args.render and i == 0} for i, name in enumerate(test)]
    console = Console(stderr=True)
    progress = RunProgress(len(jobs), console)
    stream = run_jobs(args, jobs, code_test_btf, progress, gpus_per_task=0.0, lost=lost_test_btf, log=console.print)
    done = {r["name"]: r for r in stream}
    results = [done[name] for name in test]
    ok = [r for r in results if r["status"] == "ok"]
    failed = [f"{r['name']}: {r['error']}" for r in results if r["status"] != "ok"]
    rows = [row for r in ok for row in r["rows"]]
    neu_rows = [row for r in ok for row in r["neu_rows"]]
    models = {(r["name"], mult): sp for r in ok for mult, sp in r["models"].items()}
    taus = {m: tuple(t * m for t in tau_l) for m in mults}                 # tau_t per rate
    first = results[0].get("btf_and_decomposition")
    if failed:
        print("failed test BTFs (not in the tables): " + "; ".join(failed))
    if not ok:
        raise SystemExit("no test BTF was coded")
    table("SparseBTF vs PCA at equal per-BTF storage (MSE on linear RGB apparent BRDF and in log-YUV)", rows)
    table("summary per rate: test BTFs where SparseBTF's MSE is below PCA's in both spaces, in one, in neither; "
          "geometric means of PCA MSE / sparse MSE (> 1: SparseBTF better)", win_summary(rows, mults, taus))

    if args.neubrdf:
        table(f"NeuBRDF + neural texture at SparseBTF's per-BTF bytes (N_side {args.neubrdf_nside}, k 8, b 6, MLP 2 x "
              f"{args.neubrdf_hidden}; {args.neubrdf_steps} steps of {args.neubrdf_batch} table entries)", neu_rows)

    if args.render and first is None:
        print(f"--render: skipped, test BTF {test[0]} failed")
    elif args.render:
        name = test[0]
        # the SparseBTF is rendered through its coefficient-space eval (Eq. 6, the paper's runtime path: angular
        # interpolation in log space) and through its decoded table (linear interpolation, as the reference)
        fig_mult = 4 if 4 in mults else mults[-1]
        fig = models[(name, fig_mult)]
        btf, dec = first
        figure_models = {"reference": btf, "sparse-btf Eq. 6": fig, "sparse-btf table": fig.decode()}
        total = rank_budget(fig.storage(statistics_bytes=args.statistics_bytes)["per_btf"], dirs.shape[0],
                            dirs.shape[0], args.size, args.size)
        figure_models["pca"] = fit_pca(btf, best_ranks(dec.eigenvalues, total), log_eps=dic.log_eps,
                                          decomposition=dec)
        out = Path(__file__).parent / "results"
        table(f"renders of {name} (tau x{fig_mult}, equal per-BTF bytes) under studio_small_03, {args.render_spp} spp, "
              f"written to {out}", render_figures(figure_models, out, args.render_spp, args.render_size))

    speed_mult = 2 if 2 in mults else mults[0]
    speed_btf = ok[0]["name"]
    sp = models[(speed_btf, speed_mult)]
    dev_rows = []
    devices = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])
    for device in devices:
        for mode in ("coefficient", "value"):
            sp.cfg.angular = mode
            m = sp.to(device)
            dev_rows.append({"device": device, "angular interpolation": mode,
                             "evals / s": throughput(m, args.queries, device)})
        sp.cfg.angular = "coefficient"
        sp.to("cpu")
        decoded = sp.decode()
        table_btf = type(decoded)(decoded.data.to(device), decoded.light_dirs, decoded.view_dirs)
        dev_rows.append({"device": device, "angular interpolation": "decoded full table (TabulatedBTF)",
                         "evals / s": throughput(table_btf, args.queries, device)})
    if opengl_available():
        dev_rows.append({"device": "OpenGL (EGL)", "angular interpolation": "exported GLSL (coefficient)",
                         "evals / s": glsl_throughput(sp, args.queries)})
    table(f"reconstruction throughput ({speed_btf}, tau x{speed_mult}, 4 texels x 3x3 direction bins per query)",
          dev_rows)


if __name__ == "__main__":
    main()
