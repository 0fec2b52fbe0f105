"""SparseBTF vs PCA at equal per-BTF bytes on BTFs generated from real PBR texture sets (issue 33's must-show).

    python benchmarks/studies/btf/btf_real.py --dirs rings:3x30 --dictionary default --json r17.json
    python benchmarks/studies/btf/btf_real.py --dirs ubo151 --dictionary d151.nmat --json r151.json
    python benchmarks/studies/btf/btf_real.py --test Wood092_1K#1 ...          # one row's BTF only
    python benchmarks/studies/btf/btf_real.py --factor r17.json r151.json       # per-BTF ratio at one set vs the other
    python benchmarks/studies/btf/btf_real.py --interreflection 16 --json r17_ir.json   # measured-like effects of the generator
    python benchmarks/studies/btf/btf_real.py --fibres 0.8 --fibre-direction grain --json r17_fib.json

Test BTFs: every texture set under --shared at --tiles disjoint size x size crops, one texture texel per BTF
texel (crop, never resample: the patch counts texels), tile t at row = column = --crop-at + t x size, relief
--relief x the set's height scale; named `<set>#<t>`. They are generated once per direction set and kept as
float32 `.nbtf` files under --cache. The dictionary is `default` (shipped, 17 x 17 directions) or a file from
`neumat fit-dictionary`; it must not have been trained on a test set (checked against its recorded BTFs).

Per BTF and rate (tau_t = the dictionary's tau_l x --mults): SparseBTF coded with the dictionary (one projection
for all rates, `SparseBTF.encode_rates`), then PCA in the same log-YUV space (`pca_btf.decompose` once,
`best_ranks`) given SparseBTF's per-BTF bytes, charged for its means and bases, once per accounting of
SparseBTF's per-image statistics in --statistics-bytes (4: float32 as the authors' files, 2: float16; only
PCA's budget changes). "sparse / PCA" < 1: SparseBTF better. MSE on linear RGB apparent BRDF and in log-YUV.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import torch

from .btf import log_mse, table

from neumat.methods.sparse_btf.pca_solve import best_ranks, decompose, fit_pca        
from neumat.io.btf import write_btf                                  
from neumat.io.texture_set import load_texture_set                   
from neumat.methods.sparse_btf.pca import rank_budget                        
from neumat.methods.sparse_btf.model import SparseBTF, mse                  
from neumat.methods.sparse_btf.dictionary import BTFDictionary            
from neumat.reflectance.btf import direction_set, read_btf           
from neumat.reflectance.btf_generate import generate_btf, texture_tile
from neumat.reflectance.procedural_texture import RELIEF, parse_material, procedural_texture_set


def test_names(args) -> list[str]:
    """`<set>#<tile>` for every texture set under --shared and tile, or the names in --test."""
    if args.test:
        return args.test.split(",")
    sets = sorted(p.name for p in Path(args.shared).iterdir() if p.is_dir())
    return [f"{s}#{t}" for s in sets for t in range(args.tiles)]


def source_texels(args) -> int:
    """Texture-set texels per tile side: --size / --scale (1:1 by default)."""
    return round(args.size / args.scale)


def test_btf(name: str, args, dirs):
    """The BTF of `<set>#<tile>` or `procedural:<class>[~<variant>]` (layout seed 1, relief 4, a control) at --dirs
    (read from --cache when generated before)."""
    if name.startswith("procedural:"):
        folder, tile, at = name.removeprefix("procedural:").replace("~", "v"), 0, 0
    else:
        folder, tile = name.rsplit("#", 1)
        at = args.crop_at + int(tile) * source_texels(args)
    effects = (f"{f'_ir{args.interreflection}' if args.interreflection else ''}"
               + (f"_f{args.fibres:g}" + args.fibre_direction.replace(":", "") if args.fibres else ""))
    path = Path(args.cache) / (f"{folder}_{tile}_{args.size}_{at}_r{args.relief:g}{f'_n{args.noise:g}' if args.noise else ''}"
                               f"{f'_s{args.scale:g}' if args.scale != 1 else ''}{effects}_{args.dirs.replace(':', '')}.nbtf")
    if path.is_file():
        return read_btf(path), 0.0
    t = time.perf_counter()
    if name.startswith("procedural:"):
        kind, variant = parse_material(name.removeprefix("procedural:"))
        crop, relief = procedural_texture_set(kind, args.size, seed=1, variant=variant), RELIEF   # as btf.py
    else:
        ts = load_texture_set(Path(args.shared) / folder)
        if at + source_texels(args) > min(ts.size):
            raise SystemExit(f"{name}: tile at {at} + {source_texels(args)} texels leaves the {ts.size} texture set")
        crop, relief = texture_tile(ts, args.size, crop=source_texels(args), row=at, col=at)
        relief *= args.relief
    btf = generate_btf(crop, dirs, dirs, relief=relief, spp=args.spp, noise=args.noise,
                       interreflection=args.interreflection, fibres=args.fibres, fibre_direction=args.fibre_direction)
    seconds = time.perf_counter() - t
    path.parent.mkdir(parents=True, exist_ok=True)
    write_btf(path, btf, dtype="float32", extra={"source": folder, "row": at, "col": at, "relief": relief})
    return read_btf(path), seconds


def score(name: str, btf, dic: BTFDictionary, mults: list[int], args) -> list[dict]:
    """Rows of one test BTF: per rate and statistics accounting, SparseBTF and PCA at its bytes."""
    n_l, n_v, h, w, _ = btf.data.shape
    taus = [tuple(t * m for t in dic.tau_train) for m in mults]
    t = time.perf_counter()
    coded = SparseBTF.encode_rates(btf, dic, taus)
    code_s = time.perf_counter() - t
    budgets = {(m, b): sp.storage(statistics_bytes=b)["per_btf"] for m, sp in zip(mults, coded)
               for b in args.statistics_bytes}
    ranks_total = {k: rank_budget(v, n_l, n_v, h, w) for k, v in budgets.items()}
    t = time.perf_counter()
    dec = decompose(btf, dic.log_eps, max(ranks_total.values()))
    pca_s = time.perf_counter() - t
    y = dec.eigenvalues[0].double()
    y_total = float(dec.total[0]) if dec.total is not None else float(y.sum())
    residual = {k: 1 - float(y[:k].sum()) / y_total for k in (1, 3)}   # near-separable BTFs: small
    rows = []
    for mult, tau, sp in zip(mults, taus, coded):
        decoded = sp.decode()
        s_lin, s_log = mse(btf, decoded), log_mse(btf, decoded, dic.log_eps)
        del decoded
        for b in args.statistics_bytes:
            st = sp.storage(statistics_bytes=b)
            ranks = best_ranks(dec.eigenvalues, ranks_total[(mult, b)])
            pca = fit_pca(btf, ranks, log_eps=dic.log_eps, decomposition=dec).decode()
            p_lin, p_log = mse(btf, pca), log_mse(btf, pca, dic.log_eps)
            rows.append({"btf": name, "directions": f"{n_l}x{n_v}", "texels": f"{h}x{w}", "tau x": mult,
                         "tau_t (Y,U,V)": str(tau), "statistics bytes": b, "per-BTF bytes": st["per_btf"],
                         "statistics share": st["statistics"] / st["per_btf"], "sparse MSE": s_lin,
                         "PCA ranks": str(ranks), "PCA MSE": p_lin, "sparse / PCA MSE": s_lin / p_lin,
                         "sparse log MSE": s_log, "PCA log MSE": p_log, "sparse / PCA log MSE": s_log / p_log,
                         "Y residual after 1 PC": residual[1], "after 3 PCs": residual[3],
                         "coding s (all rates)": code_s, "PCA decomposition s": pca_s})
    return rows


def geo_mean(values) -> float:
    values = list(values)
    return math.exp(sum(map(math.log, values)) / len(values))


def summary(rows: list[dict]) -> list[dict]:
    """Per rate and accounting: BTFs SparseBTF wins in both spaces, and geometric-mean ratios."""
    out = []
    for key in dict.fromkeys((r["tau x"], r["statistics bytes"]) for r in rows):
        mine = [r for r in rows if (r["tau x"], r["statistics bytes"]) == key]
        out.append({"tau x": key[0], "statistics bytes": key[1], "BTFs": len(mine),
                    "sparse wins (both spaces)": sum(r["sparse / PCA MSE"] < 1 and r["sparse / PCA log MSE"] < 1
                                                     for r in mine),
                    "sparse / PCA MSE (geo. mean)": geo_mean(r["sparse / PCA MSE"] for r in mine),
                    "sparse / PCA log MSE (geo. mean)": geo_mean(r["sparse / PCA log MSE"] for r in mine),
                    "statistics share": mine[0]["statistics share"]})
    return out


def factor(a_path: str, b_path: str) -> None:
    """Per BTF, rate and accounting: the SparseBTF / PCA ratios of run A and run B and B's over A's."""
    def load(paths: str) -> dict:                                       # "x.json" or "x.json,y.json" (runs in parts)
        parts = [json.loads(Path(p).read_text()) for p in paths.split(",")]
        return {"command": " ; ".join(p["command"] for p in parts), "rows": [r for p in parts for r in p["rows"]]}

    a, b = load(a_path), load(b_path)
    key = lambda r: (r["btf"], r["tau x"], r["statistics bytes"])          # noqa: E731
    by_b = {key(r): r for r in b["rows"]}
    rows = []
    for r in a["rows"]:
        s = by_b.get(key(r))
        if s is None:
            continue
        rows.append({"btf": r["btf"], "tau x": r["tau x"], "statistics bytes": r["statistics bytes"],
                     "A directions": r["directions"], "B directions": s["directions"],
                     "A ratio": r["sparse / PCA MSE"], "B ratio": s["sparse / PCA MSE"],
                     "B / A": s["sparse / PCA MSE"] / r["sparse / PCA MSE"],
                     "A log ratio": r["sparse / PCA log MSE"], "B log ratio": s["sparse / PCA log MSE"],
                     "B / A (log)": s["sparse / PCA log MSE"] / r["sparse / PCA log MSE"]})
    if not rows:
        raise SystemExit(f"{a_path} and {b_path} share no (btf, tau x, statistics bytes) row")
    print(f"A: {a['command']}\nB: {b['command']}")
    table("SparseBTF / PCA MSE ratio, run A vs run B (same BTF crops)", rows)
    out = []
    for key2 in dict.fromkeys((r["tau x"], r["statistics bytes"]) for r in rows):
        mine = [r for r in rows if (r["tau x"], r["statistics bytes"]) == key2]
        out.append({"tau x": key2[0], "statistics bytes": key2[1], "BTFs": len(mine),
                    "A ratio (geo. mean)": geo_mean(r["A ratio"] for r in mine),
                    "B ratio (geo. mean)": geo_mean(r["B ratio"] for r in mine),
                    "B / A (geo. mean)": geo_mean(r["B / A"] for r in mine),
                    "A log ratio (geo. mean)": geo_mean(r["A log ratio"] for r in mine),
                    "B log ratio (geo. mean)": geo_mean(r["B log ratio"] for r in mine),
                    "B / A log (geo. mean)": geo_mean(r["B / A (log)"] for r in mine)})
    table("geometric means", out)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dirs", default="rings:3x30", help="direction set (neumat.reflectance.btf.direction_set)")
    ap.add_argument("--dictionary", default="default", help="'default' (shipped) or a fit-dictionary .nmat file")
    ap.add_argument("--shared", default="../shared/data/svbrdf", help="folder of the PBR texture sets")
    ap.add_argument("--test", default="", help="comma-separated <set>#<tile> names (default: every set and tile)")
    ap.add_argument("--tiles", type=int, default=2, help="disjoint tiles per texture set")
    ap.add_argument("--size", type=int, default=50, help="texels per tile side (crop, 1:1)")
    ap.add_argument("--crop-at", type=int, default=300, help="row = column of tile 0")
    ap.add_argument("--scale", type=float, default=1.0,
                    help="BTF texels per texture-set texel (a factor experiment: 2 magnifies each crop of "
                         "size / 2 texels 2x, so its features span 2x more texels; default 1: crop, never resample)")
    ap.add_argument("--relief", type=float, default=4.0, help="relief x the set's height scale")
    ap.add_argument("--spp", type=int, default=1)
    ap.add_argument("--noise", type=float, default=0.0, help="relative sensor noise of the test BTFs (generate_btf)")
    ap.add_argument("--interreflection", type=int, default=0,
                    help="hemisphere directions per hit for one bounce of inter-reflection (generate_btf; 0: none)")
    ap.add_argument("--fibres", type=float, default=0.0, help="fibre anisotropy in [0, 1] (generate_btf; 0: none)")
    ap.add_argument("--fibre-direction", default="grain", help="fibre field: grain, weave:<p>, angle:<deg>")
    ap.add_argument("--mults", default="1,4", help="tau_t = the dictionary's tau_l x these")
    ap.add_argument("--statistics-bytes", default="4,2", help="accountings of the per-image statistics (4, 2)")
    ap.add_argument("--cache", default="../btfreal_cache", help="folder of the generated test BTFs")
    ap.add_argument("--json", default="", help="also write the rows here (for --factor)")
    ap.add_argument("--generate-only", action="store_true", help="generate the test BTFs into --cache and exit")
    ap.add_argument("--factor", nargs=2, metavar=("A.json", "B.json"),
                    help="compare two runs' ratios and exit (a comma-separated list of JSON files for a run in parts)")
    args = ap.parse_args()
    if args.factor:
        factor(*args.factor)
        return
    args.statistics_bytes = [int(b) for b in args.statistics_bytes.split(",")]
    if any(b not in (2, 4) for b in args.statistics_bytes):
        raise SystemExit(f"--statistics-bytes {args.statistics_bytes}: expected 4 and/or 2")
    command = "python benchmarks/studies/btf/btf_real.py " + " ".join(sys.argv[1:])
    dirs = direction_set(args.dirs)
    names = test_names(args)
    if args.generate_only:
        for name in names:
            print(f"{name}: generated in {test_btf(name, args, dirs)[1]:.1f} s", flush=True)
        return
    dic = BTFDictionary.load(args.dictionary)
    trained_on = [str(b) for b in dic.info.get("btfs", [])]
    if any(n.split("#")[0].removeprefix("procedural:") in (t, Path(t).stem) or n.split("#")[0] in t
           for n in names for t in trained_on):
        raise SystemExit(f"{args.dictionary} was trained on a test set: {trained_on}")
    print(f"dictionary {args.dictionary}: K={dic.num_dictionaries}, tau_l={dic.tau_train}, patch {dic.patch}, "
          f"{dic.info.get('points')} data points per channel from {trained_on}, iterations {dic.info.get('iterations')}")
    mults = [int(m) for m in args.mults.split(",")]
    rows = []
    for name in names:
        btf, gen_s = test_btf(name, args, dirs)
        print(f"{name}: generated in {gen_s:.1f} s" if gen_s else f"{name}: from {args.cache}", flush=True)
        rows += score(name, btf, dic, mults, args)
        del btf
        if args.json:                                                   # after every BTF: a cut run keeps its rows
            Path(args.json).write_text(json.dumps({"command": command, "rows": rows}, indent=1))
    table(f"SparseBTF vs PCA at equal per-BTF bytes ({command})", rows)
    table("summary (sparse / PCA < 1: SparseBTF better)", summary(rows))


if __name__ == "__main__":
    main()
