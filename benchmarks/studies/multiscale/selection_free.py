"""Issue 55's selection-free protocol: 64^2 crops at origins drawn from a seed (4 per shared texture set, 1 per
procedural detail set), each fitted through the CLI's default recipe (`neumat fit SET --model M --source-option
crop=64 --source-option crop_origin=R,C --source-option samples=8 --seed S`) and scored as the docs do (`neumat eval
... --source-option samples=64 --scales 9 --resolution 48 --no-image`), with each crop's texture statistics
(`neumat.reflectance.texture_statistics`) beside it and each fit's loss history (final against lowest, as the
trainer's FitWarning reads it), and the commit the job ran at (rows from session 64 on).

Jobs run as subprocesses of the installed CLI, `--workers` at a time, one thread each; every finished job appends one
JSON line to OUT/jobs.jsonl (or the file `--jobs` names), so a rerun with the same OUT resumes. `--report` prints the
per-crop and per-regime tables from that file. `--jobs` at a committed ledger (`results/*_jobs.jsonl`, inside the
checkout) keeps each finished fit where a session that ends early leaves it, as an uncommitted change, and a rerun on
another machine takes up where that one stopped (a fit takes 5-12 minutes; the whole protocol at two seeds, ~8 CPU
hours, is longer than a session).

Usage: python -m benchmarks.studies.multiscale.selection_free OUT [--workers 2] [--models multiscale,tripleplane]
       [--seeds 0,1] [--steps N] [--set KEY=VALUE ... --variant NAME] [--only SET,...] [--jobs FILE] [--report]
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import torch

CROP = 64
CROPS_PER_SHARED_SET = 4
PROCEDURAL_KINDS = ("scratches", "brushed", "foil", "chainmail", "polished")
PROCEDURAL_SIZE = 256
PROTOCOL_SEED = 55


def neumat() -> str:
    return str(Path(sys.executable).with_name("neumat"))


def crops(out: Path) -> list[dict]:
    """Every crop of the protocol: set folder, name and (row, col) origin drawn from PROTOCOL_SEED."""
    from neumat.io.shared_data import shared_data_dir
    from neumat.io.texture_set import load_texture_set

    data = shared_data_dir()
    sets = sorted(p for p in (data / "svbrdf").iterdir() if p.is_dir()) if data else []
    procedural = out / "procedural"
    for kind in PROCEDURAL_KINDS:
        folder = procedural / kind
        if not folder.exists():
            subprocess.run([neumat(), "data", "texture-set", kind, "-o", str(folder), "--size", str(PROCEDURAL_SIZE),
                            "--threads", "1"], check=True, capture_output=True)
        sets.append(folder)
    g = torch.Generator().manual_seed(PROTOCOL_SEED)
    out_crops = []
    for folder in sets:
        h, w = load_texture_set(folder).size
        n = 1 if folder.parent == procedural else CROPS_PER_SHARED_SET
        for _ in range(n):
            r = int(torch.randint(0, h - CROP + 1, (1,), generator=g))
            c = int(torch.randint(0, w - CROP + 1, (1,), generator=g))
            out_crops.append({"set": str(folder), "name": folder.name, "origin": [r, c]})
    return out_crops


def crop_stats(crop: dict) -> dict:
    from neumat.io.texture_set import load_texture_set
    from neumat.reflectance.texture_statistics import texture_statistics

    ts = load_texture_set(crop["set"], crop=CROP, crop_origin=tuple(crop["origin"]))
    return texture_statistics(ts, footprints=(1, 4, 16))


def run_job(job: dict, steps: int | None, overrides: list[str], samples: int) -> dict:
    """Fit and score one (crop, model, seed); the row of jobs.jsonl."""
    from neumat.fit.trainer import WARMUP_FRACTION, record_loss

    src_opts = ["--source-option", f"crop={CROP}", "--source-option",
                f"crop_origin={job['origin'][0]},{job['origin'][1]}"]
    env = dict(os.environ, OMP_NUM_THREADS="1")
    with tempfile.TemporaryDirectory(prefix="neumat-sf-") as tmp:
        nmat, ckpt = Path(tmp) / "m.nmat", Path(tmp) / "m.ckpt"
        # the targets' footprint positions: the source's count and the recipe option that would override it
        cmd = [neumat(), "fit", job["set"], "--model", job["model"], *src_opts, "--source-option", f"samples={samples}",
               "--set", f"option.target_samples={samples}", "--seed", str(job["seed"]), "-o", str(nmat),
               "--checkpoint", str(ckpt), "--threads", "1", "-q"]
        if steps is not None:
            cmd += ["--steps", str(steps)]
        for kv in overrides:
            cmd += ["--set", kv]
        t0 = time.time()
        fit = subprocess.run(cmd, capture_output=True, text=True, env=env)
        fit_s = time.time() - t0
        if fit.returncode != 0:
            return {**job, "status": "error", "error": (fit.stderr.strip().splitlines() or ["?"])[-1]}
        history = torch.load(ckpt, weights_only=False)["history"]
        losses = [record_loss(r) for r in history]
        settled = losses[int(len(losses) * WARMUP_FRACTION):]  # as the trainer's FitWarning reads a fit
        ev = subprocess.run([neumat(), "eval", str(nmat), "--against", job["set"], *src_opts, "--source-option",
                             "samples=64", "--scales", "9", "--resolution", "48", "--no-image", "--json",
                             "--threads", "1", "-q"], capture_output=True, text=True, env=env)
        if ev.returncode != 0:
            return {**job, "status": "error", "error": (ev.stderr.strip().splitlines() or ["?"])[-1]}
        scores = json.loads(ev.stdout)
    warned = [line for line in fit.stderr.splitlines() if "lowest" in line]
    return {**job, "status": "ok", "fit_s": fit_s, "final_loss": losses[-1], "best_loss": min(settled),
            "warning": warned, "scales": scores["scales"]}


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.studies.multiscale.selection_free",
                                     description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("out", type=Path)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--models", default="multiscale,tripleplane")
    parser.add_argument("--seeds", default="0,1")
    parser.add_argument("--steps", type=int, default=None, help="override the recipe's steps (budget study)")
    parser.add_argument("--set", dest="overrides", action="append", default=[],
                        help="KEY=VALUE passed to `neumat fit --set` (controlled experiments; name them with --variant)")
    parser.add_argument("--variant", default=None, help="the label of this --set / --samples combination")
    parser.add_argument("--samples", type=int, default=8, help="footprint samples of the training targets")
    parser.add_argument("--only", default=None, help="comma-separated set names to restrict to")
    parser.add_argument("--crops-per-set", type=int, default=None, help="only the first N crops of each set")
    parser.add_argument("--report", action="store_true")
    parser.add_argument("--jobs", type=Path, default=None, help="the JSON-lines file of finished jobs (default "
                        "OUT/jobs.jsonl): read to resume, appended to as each job ends")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    crops_file = args.out / "crops.json"
    if not crops_file.exists():
        cs = crops(args.out)
        for c in cs:
            c["stats"] = crop_stats(c)
        crops_file.write_text(json.dumps(cs, indent=1))
    cs = json.loads(crops_file.read_text())
    jobs_file = args.jobs or args.out / "jobs.jsonl"
    if args.report:
        from .selection_free_report import report
        print(report(cs, [json.loads(line) for line in jobs_file.read_text().splitlines()]))
        return 0
    done = set()
    if jobs_file.exists():
        for line in jobs_file.read_text().splitlines():
            r = json.loads(line)
            done.add((r["name"], tuple(r["origin"]), r["model"], r["seed"], r.get("steps"), r.get("variant")))
    only = set(args.only.split(",")) if args.only else None
    if args.crops_per_set is not None:
        cs = [c for c in cs if [d["origin"] for d in cs if d["name"] == c["name"]].index(c["origin"]) < args.crops_per_set]
    jobs = [{"set": c["set"], "name": c["name"], "origin": c["origin"], "model": m, "seed": int(s),
             "steps": args.steps, "variant": args.variant}
            for s in args.seeds.split(",") for c in cs for m in args.models.split(",")
            if (only is None or c["name"] in only)
            and (c["name"], tuple(c["origin"]), m, int(s), args.steps, args.variant) not in done]
    if (args.overrides or args.samples != 8) and args.variant is None:
        parser.error("--set and --samples need a --variant label")
    print(f"{len(jobs)} jobs to run", file=sys.stderr)

    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                            cwd=Path(__file__).parent).stdout.strip() or None

    def one(job):
        row = {**run_job(job, args.steps, args.overrides, args.samples), "commit": commit}
        with open(jobs_file, "a") as f:
            f.write(json.dumps(row) + "\n")
        print(f"{job['name']} {job['origin']} {job['model']} seed {job['seed']}: {row['status']} "
              f"{row.get('scales', {}).get('flip_mean', row.get('error'))}", file=sys.stderr, flush=True)

    with ThreadPoolExecutor(args.workers) as pool:
        list(pool.map(one, jobs))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
