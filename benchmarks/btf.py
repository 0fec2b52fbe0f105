"""SparseBTF benchmark: quality vs coefficients, storage, PCA at equal storage, training / coding time and
reconstruction throughput (CPU, and CUDA when available), coefficient- vs value-space interpolation.

    python benchmarks/btf.py                       # procedural texture sets (no data needed)
    python benchmarks/btf.py --size 40 --dirs rings:3x30 --patch 10 --dictionaries 4 --iterations 10
    python benchmarks/btf.py --shared ../shared/data/svbrdf   # generated from the real PBR sets

Training set: the first two materials; test set: the others (never seen in training).
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import torch
from rich.console import Console
from rich.table import Table

from neumat.core.query import Query
from neumat.models.pca_btf import PCABTF, ranks_for_bytes
from neumat.models.sparse_btf import SparseBTF, mse
from neumat.models.sparse_dictionary import train_dictionary
from neumat.reflectance.btf import direction_set
from neumat.reflectance.btf_generate import generate_btf, procedural_texture_set, texture_tile


def table(title, rows):
    t = Table(title=title)
    for k in rows[0]:
        t.add_column(k)
    for r in rows:
        t.add_row(*(f"{v:.4g}" if isinstance(v, float) else str(v) for v in r.values()))
    Console(width=220).print(t)


def materials(args, dirs):
    if args.shared:
        from neumat.io.texture_set import load_texture_set
        out = {}
        for folder in sorted(Path(args.shared).iterdir()):
            ts = load_texture_set(folder)
            tile, relief = texture_tile(ts, args.size, crop=min(256, *ts.size))
            out[ts.name] = generate_btf(tile, dirs, dirs, relief=relief * args.relief, spp=args.spp)
        return out
    kinds = ["bumps", "weave", "bricks", "dents", "ridges"]
    return {k: generate_btf(procedural_texture_set(k, args.size, seed=1), dirs, dirs, relief=args.relief * 4,
                            spp=args.spp) for k in kinds}


def throughput(model, n, device, reps=3):
    g = torch.Generator().manual_seed(0)
    wi = torch.nn.functional.normalize(torch.rand(n, 3, generator=g) - torch.tensor([0.5, 0.5, -0.2]), dim=-1)
    wo = torch.nn.functional.normalize(torch.rand(n, 3, generator=g) - torch.tensor([0.5, 0.5, -0.2]), dim=-1)
    q = Query(wi, wo, uv=torch.rand(n, 2, generator=g)).to(device)
    model.eval(q)
    if device == "cuda":
        torch.cuda.synchronize()
    t = time.perf_counter()
    for _ in range(reps):
        model.eval(q)
    if device == "cuda":
        torch.cuda.synchronize()
    return n * reps / (time.perf_counter() - t)


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
    ap.add_argument("--shared", default="")
    args = ap.parse_args()
    dirs = direction_set(int(args.dirs) if args.dirs.isdigit() else args.dirs)
    tau_l = tuple(int(t) for t in args.tau_train.split(","))

    t = time.perf_counter()
    btfs = materials(args, dirs)
    gen_s = time.perf_counter() - t
    names = list(btfs)
    train, test = names[:2], names[2:]
    t = time.perf_counter()
    dic = train_dictionary([btfs[k] for k in train], args.dictionaries, tau_l, args.patch, max_iters=args.iterations,
                           progress=True)
    train_s = time.perf_counter() - t
    print(f"{len(names)} BTFs of {args.size}x{args.size} texels x {dirs.shape[0]}x{dirs.shape[0]} directions "
          f"generated in {gen_s:.1f} s; dictionary (K={args.dictionaries}, tau_l={tau_l}, patch {args.patch}) "
          f"trained on {train} in {train_s:.1f} s ({torch.get_num_threads()} threads; the paper: 101 h on 128 "
          f"cores); iterations {dic.info['iterations']}")

    rows, models = [], {}
    for name in test:
        for mult in (1, 2, 4, 8, 16):
            tau = tuple(t * mult for t in tau_l)
            t = time.perf_counter()
            sp = SparseBTF.encode(btfs[name], dic, tau)
            code_s = time.perf_counter() - t
            st = sp.storage()
            ranks = ranks_for_bytes(st["per_btf"], dirs.shape[0], dirs.shape[0], args.size, args.size, split=tau)
            pca = PCABTF.fit(btfs[name], ranks, log_eps=dic.log_eps)
            rows.append({"btf": name, "tau_t (Y,U,V)": str(tau), "coefficients": st["coefficients"],
                         "sparse MSE": mse(btfs[name], sp.decode()), "PCA ranks": str(ranks),
                         "PCA MSE": mse(btfs[name], pca.decode()), "per-BTF bytes": st["per_btf"],
                         "PCA bytes": pca.storage()["total"], "total bytes (+dict)": st["total"],
                         "compression": st["compression_ratio"], "coding s": code_s})
            models[(name, mult)] = sp
    table("SparseBTF vs PCA at equal per-BTF storage (MSE on linear RGB apparent BRDF)", rows)

    sp = models[(test[0], 2)]
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
    table(f"reconstruction throughput ({test[0]}, tau x2, 4 texels x 3x3 direction bins per query)", dev_rows)


if __name__ == "__main__":
    main()
