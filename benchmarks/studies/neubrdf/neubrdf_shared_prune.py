"""NeuBRDF's sparse-measurement pruning (paper Sec. 3.2.1) and shared codebooks (Sec. 3.3), through the CLI.

Every fit is one `neumat fit` command and every score one `neumat eval --no-image --json` (held-out
reflectance errors over `--n-configs` fresh cosine-weighted (wi, wo) pairs against the source), run as
subprocesses with one torch thread; the rows print the command.

--part prune: each shared RGL file (../shared/data/rgl) fitted by replaying its measurement directions
(`--set queries=replay`, `neumat.fit.measured_samples.rgl_samples`: 8 incident elevations at one azimuth x
32 x 32 outgoing nodes), with the single measured azimuth as is (`measured_azimuths=1`: the raw sparse
measurement) or rotated to 64 azimuths (isotropy), unpruned vs pruned (`--set prune=true`), and for
reference fitted online to the file's interpolant at cosine-weighted queries (the default). Also: the share
of hemisphere pixels that hold a measurement and of grid slots that the pruned grids read, and the error at
the measured samples themselves (training error, 2^16 draws).

--part shared: a cluster of MERL-like NBRDF tables (../shared/data/merl/nbrdf_fits/*.h5) fitted one by one
(`--model neubrdf`) and jointly (`neumat fit A B C D --model shared-neubrdf`, one MLP and codebook, an index
grid each) at the same steps; the joint batch is t times the per-material one, so every material sees the
same number of queries. Each member is scored with `neumat eval shared.nmat --member i`.

--part clusters: the paper's clustering through the CLI: the 25 MERL-like tables (`neumat data convert
NAME.h5 NAME.binary`, cached in --tables) and the five RGL files in one `neumat fit-clusters ... -k K`
(autoencoder + k-means, one shared-neubrdf per cluster, each member scored against its source), then each
material fitted alone (`--model neubrdf`) at about its shared bytes (the largest index_bits / hidden whose
NeuBRDF is no larger than the material's share of its cluster's model) with the same steps and batch, and
scored with `neumat eval --no-image --json` on the same held-out queries.

    PYTHONPATH=src python benchmarks/studies/neubrdf/neubrdf_shared_prune.py --part prune [--nside 16 --steps 1000]
    PYTHONPATH=src python benchmarks/studies/neubrdf/neubrdf_shared_prune.py --part shared [--cluster paints --nside 16 --steps 1000]
    PYTHONPATH=src python benchmarks/studies/neubrdf/neubrdf_shared_prune.py --part clusters [--k 6 --nside 16 --steps 500]
"""
from __future__ import annotations

import argparse
import json
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DATA = Path("..") / "shared" / "data"  # relative to ROOT, where the commands run
RGL = ("cc_ibiza_sunset_rgb", "cc_iris_purple_gem_rgb", "colodur_napoli_4f_rgb", "paper_white_rgb",
       "vch_golden_yellow_rgb")
CLUSTERS = {"paints": ("gold-paint", "light-red-paint", "silver-paint", "white-paint"),
            "plastics": ("green-plastic", "red-specular-plastic", "yellow-plastic", "specular-green-phenolic"),
            "metals": ("alum-bronze", "nickel", "steel", "two-layer-silver")}
ENV = {**os.environ, "PYTHONPATH": str(ROOT / "src"), "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


def neumat(*args: str) -> tuple[str, str]:
    """Run `python -m neumat ARGS` (one thread); returns (the command as text, stdout)."""
    cmd = [sys.executable, "-m", "neumat", *args]
    out = subprocess.run(cmd, env=ENV, capture_output=True, text=True, cwd=ROOT)
    if out.returncode:
        raise SystemExit(f"failed: {shlex.join(cmd)}\n{out.stdout}\n{out.stderr}")
    return "neumat " + shlex.join(args), out.stdout


def fit(sources: list[str], out: Path, sets: list[str], steps: int, model: str = "neubrdf") -> tuple[str, float]:
    """`neumat fit`; returns (command, fit seconds as the CLI reports them)."""
    args = [*sources, "--model", model, *[a for s in sets for a in ("--set", s)], "--steps", str(steps),
            "--device", "cpu", "-q", "-o", str(out)]
    cmd, text = neumat("fit", *args)
    seconds = float(re.search(r"steps, ([0-9.]+) s", text).group(1))
    return cmd, seconds


def evaluate(model: Path, against: str, n: int, member: int | None = None) -> dict:
    extra = [] if member is None else ["--member", str(member)]
    _, text = neumat("eval", str(model), "--against", against, "--no-image", "--json", "--n-configs", str(n),
                     "--device", "cpu", *extra)
    return json.loads(text)


def coverage(path: str, nside: int, azimuths: int) -> dict:
    """Share of hemisphere pixels holding a measured wi / wo, and of grid slots the pruned grids read."""
    import torch

    from neumat.catalog.open_material import open_material
    from neumat.fit.measured_samples import rgl_samples
    from neumat.methods.neubrdf.model import NeuBRDF
    from neumat.nn import healpix as hpx

    s = rgl_samples(open_material(str(ROOT / path)), azimuths)
    z = hpx.pix2vec(nside, torch.arange(12 * nside ** 2))[:, 2]
    hemi = int((z >= -1e-12).sum())
    sup = [int(hpx.supervised_pixels(nside, hpx.hemisphere_direction(w, south)).sum())
           for w, south in ((s.wi, False), (s.wo, True))]
    model = NeuBRDF(nside=nside)
    model.prune(s.wi, s.wo)
    used = model.used_slots()
    return {"samples": len(s), "wi px": f"{sup[0] / hemi:.3f}", "wo px": f"{sup[1] / hemi:.3f}",
            "slots read": f"{float(used.float().mean()):.3f}"}


def at_measurements(model: Path, path: str, azimuths: int, n: int) -> float:
    """log_err of the saved model at n draws of the measured samples it was fitted to (training error)."""
    import torch

    from neumat.catalog.modelfile import load_model
    from neumat.catalog.open_material import open_material
    from neumat.fit.measured_samples import rgl_samples
    from neumat.fit.query_samplers import replay_queries
    from neumat.metrics.hdr import reflectance_errors

    torch.set_num_threads(1)
    s = rgl_samples(open_material(str(ROOT / path)), azimuths)
    return reflectance_errors(load_model(model), s, n=n, query_sampler=replay_queries(s))["log_err"]


def part_prune(a) -> list[dict]:
    rows = []
    sets = [f"nside={a.nside}", f"batch_size={a.batch}", f"lr_decay_every={max(a.steps // 4, 1)}"]
    for name in a.materials.split(",") if a.materials else RGL:
        path = str(DATA / "rgl" / f"{name}.bsdf")
        arms = [(None, False)] + [(az, prune) for az in (1, 64) for prune in (False, True)]
        for az, prune in arms:
            tag = "online" if az is None else f"az{az}.{'pruned' if prune else 'full'}"
            out = Path(a.work) / f"{name}.{tag}.nmat"
            extra = [] if az is None else ["queries=replay", f"measured_azimuths={az}"] + (["prune=true"] * prune)
            cmd, seconds = fit([path], out, sets + extra, a.steps)
            e = evaluate(out, path, a.n_configs)
            cov = coverage(path, a.nside, az) if az is not None else {}
            rows.append({"material": name.removesuffix("_rgb"),
                         "queries": "cosine (interpolant)" if az is None else f"replay, {az} azimuth(s)",
                         "pruned": prune, "samples": cov.get("samples", "-"), "wi px": cov.get("wi px", "-"),
                         "wo px": cov.get("wo px", "-"), "slots read": cov.get("slots read", "-"),
                         "bytes": e["bytes_fp16"], "log_err held-out": round(e["log_err"], 5),
                         "log_err measured": "-" if az is None else round(at_measurements(out, path, az, 2 ** 16), 5),
                         "rmse_hdr": round(e["rmse_hdr"], 4), "fit s": round(seconds, 1), "command": cmd})
            print(json.dumps(rows[-1]), flush=True)
    return rows


def part_shared(a) -> list[dict]:
    rows = []
    base = [f"nside={a.nside}", f"lr_decay_every={max(a.steps // 4, 1)}"]
    names = CLUSTERS[a.cluster]
    paths = [str(DATA / "merl" / "nbrdf_fits" / f"{m}.h5") for m in names]
    own = a.own_set or []
    for name, path in zip(names, paths):
        out = Path(a.work) / f"{name}.neubrdf{'.' + '.'.join(own) if own else ''}.nmat"
        cmd, seconds = fit([path], out, base + [f"batch_size={a.batch}"] + own, a.steps)
        e = evaluate(out, path, a.n_configs)
        label = f"neubrdf (own{', ' + ', '.join(own) if own else ''})"
        rows.append({"material": name, "model": label, "bytes/material": e["bytes_fp16"],
                     "log_err": round(e["log_err"], 5), "rmse_hdr": round(e["rmse_hdr"], 4),
                     "mae_hdr": round(e["mae_hdr"], 5), "fit s": round(seconds, 1), "command": cmd})
        print(json.dumps(rows[-1]), flush=True)
    t = len(paths)
    if a.no_shared:
        return rows
    out = Path(a.work) / f"{a.cluster}.shared.nmat"
    cmd, seconds = fit(paths, out, base + [f"batch_size={a.batch * t}", f"num_materials={t}"], a.steps,
                       model="shared-neubrdf")
    for i, (name, path) in enumerate(zip(names, paths)):
        e = evaluate(out, path, a.n_configs, member=i)
        rows.append({"material": name, "model": f"shared-neubrdf (1 of {t})", "bytes/material": e["bytes_fp16"],
                     "log_err": round(e["log_err"], 5), "rmse_hdr": round(e["rmse_hdr"], 4),
                     "mae_hdr": round(e["mae_hdr"], 5), "fit s": round(seconds / t, 1),
                     "command": cmd + f"  # eval --member {i}"})
        print(json.dumps(rows[-1]), flush=True)
    return rows


def merl_tables(folder: Path) -> list[str]:
    """The 25 MERL-like tables as .binary files in `folder`, converted from the NBRDF networks where missing."""
    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for h5 in sorted((ROOT / DATA / "merl" / "nbrdf_fits").glob("*.h5")):
        table = folder / f"{h5.stem}.binary"
        if not table.is_file():
            neumat("data", "convert", str(h5), "-o", str(table))
        out.append(str(table))
    return out


def equal_bytes_config(nside: int, budget: float) -> dict:
    """The NeuBRDF (index_bits 5 - 9, hidden 16 - 64) with the most fp16 bytes not above `budget` (the
    smallest of them when none fits): {"index_bits", "hidden", "bytes"}."""
    from neumat.methods.neubrdf.model import NeuBRDF

    options = [{"index_bits": b, "hidden": h, "bytes": NeuBRDF(nside=nside, index_bits=b, hidden=h).size_bytes("fp16")}
               for b in range(5, 10) for h in (16, 24, 32, 48, 64)]
    fitting = [o for o in options if o["bytes"] <= budget]
    return max(fitting, key=lambda o: o["bytes"]) if fitting else min(options, key=lambda o: o["bytes"])


def part_clusters(a) -> list[dict]:
    sources = merl_tables(Path(a.tables)) + [str(DATA / "rgl" / f"{n}.bsdf") for n in RGL]
    out = Path(a.work) / f"clusters_k{a.k}"
    sets = [f"nside={a.nside}", f"batch_size={a.batch}", f"lr_decay_every={max(a.steps // 4, 1)}"]
    cmd, _ = neumat("fit-clusters", *sources, "-k", str(a.k), *[x for s in sets for x in ("--set", s)],
                    "--steps", str(a.steps), "--eval-n", str(a.n_configs), "--device", "cpu", "-q", "-o", str(out))
    print(cmd, flush=True)
    summary = json.loads((out / "clusters.json").read_text())
    sizes = {c["cluster"]: len(c["members"]) for c in summary["clusters"]}
    rows = []
    for path, m in summary["materials"].items():
        own = equal_bytes_config(a.nside, m["bytes_fp16"])
        nmat = Path(a.work) / f"{m['name']}.own_b{own['index_bits']}_h{own['hidden']}.nmat"
        own_cmd, seconds = fit([path], nmat, sets + [f"index_bits={own['index_bits']}", f"hidden={own['hidden']}"],
                               a.steps)
        e = evaluate(nmat, path, a.n_configs)
        rows.append({"material": m["name"], "cluster": m["cluster"], "member": f"{m['member']} of {sizes[m['cluster']]}",
                     "ae mse": round(m["reconstruction_mse"], 5), "shared bytes": round(m["bytes_fp16"]),
                     "shared log_err": round(m["metrics"]["log_err"], 5),
                     "shared rmse_hdr": round(m["metrics"]["rmse_hdr"], 4),
                     "own b/h": f"{own['index_bits']}/{own['hidden']}", "own bytes": e["bytes_fp16"],
                     "own log_err": round(e["log_err"], 5), "own rmse_hdr": round(e["rmse_hdr"], 4),
                     "own fit s": round(seconds, 1), "command": own_cmd})
        print(json.dumps(rows[-1]), flush=True)
    rows.sort(key=lambda r: (r["cluster"], r["material"]))
    for c in summary["clusters"]:
        print(f"cluster {c['cluster']}: {', '.join(c['members'])}: {c['bytes_fp16']} bytes, fit {c['fit_seconds']:.1f} s",
              flush=True)
    return rows


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--part", choices=("prune", "shared", "clusters"), required=True)
    p.add_argument("--nside", type=int, default=16)
    p.add_argument("--steps", type=int, default=1000)
    p.add_argument("--batch", type=int, default=4096, help="queries per step (per material)")
    p.add_argument("--n-configs", type=int, default=2 ** 17, help="held-out queries of each evaluation")
    p.add_argument("--materials", help="prune: comma-separated RGL names (default: all five shared files)")
    p.add_argument("--cluster", choices=sorted(CLUSTERS), default="paints", help="shared: the MERL-like cluster")
    p.add_argument("--own-set", action="append", help="shared: an extra --set of the own fits (e.g. index_bits=7)")
    p.add_argument("--no-shared", action="store_true", help="shared: the own fits only")
    p.add_argument("--k", type=int, default=6, help="clusters: number of clusters")
    p.add_argument("--tables", default="/work/merl_tables", help="clusters: folder of the MERL-like .binary tables")
    p.add_argument("--work", default="/tmp/neubrdf_shared_prune", help="folder for the fitted models")
    p.add_argument("--json", help="also write the rows here")
    a = p.parse_args()
    Path(a.work).mkdir(parents=True, exist_ok=True)
    rows = {"prune": part_prune, "shared": part_shared, "clusters": part_clusters}[a.part](a)
    from neumat.cli.common import print_table

    print_table(f"NeuBRDF {a.part}{' ' + a.cluster if a.part == 'shared' else ''}: N_side {a.nside}, {a.steps} steps of {a.batch}",
                [{k: v for k, v in r.items() if k != "command"} for r in rows], width=200)
    if a.json:
        Path(a.json).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
