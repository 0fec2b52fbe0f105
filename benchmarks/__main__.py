"""Entry point: `python -m benchmarks --list | SUITE [--quick] [--json] [--out FILE.json] [--work DIR]
[--ledger FILE.jsonl] [--workers N | --shard I/N]`, or `python -m benchmarks compare COMMITTED.json RERUN.json`."""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

from . import harness
from .suites import SUITES, load


def main(argv: list[str]) -> int:
    """Run one suite and print its table (or its JSON), or compare two results files (`compare`); returns the exit
    status."""
    if argv[:1] == ["compare"]:
        from . import compare

        return compare.main(argv[1:])
    parser = argparse.ArgumentParser(prog="python -m benchmarks", description=__doc__)
    parser.add_argument("suite", nargs="?", choices=SUITES, help="the suite to run")
    parser.add_argument("--list", action="store_true", help="name every suite with its budget, and exit")
    parser.add_argument("--quick", action="store_true", help="the seconds-long smoke version of the suite")
    parser.add_argument("--json", action="store_true", help="print the results JSON instead of the Markdown")
    parser.add_argument("--out", type=Path, help="write the results JSON here and the folder's README.md page "
                                                 "(committed results: benchmarks/results/<suite>/<name>.json)")
    parser.add_argument("--threads", type=int, default=1, help="CPU threads (default 1)")
    parser.add_argument("--seed", type=int, default=0, help="seed of every fit and query set")
    parser.add_argument("--repeats", type=int, default=None, help="timing samples, best taken (default: 3 quick, "
                                                                  "7 full)")
    parser.add_argument("--work", type=Path, help="keep the suite's fits here (fit-many folders, generated data): "
                                                  "the same command again resumes, refitting only what is missing "
                                                  "(for full runs longer than a sitting; default: a temporary folder)")
    parser.add_argument("--ledger", type=Path, help="a JSON-lines file of finished jobs (fits): each is added as "
                                                    "it ends, and a job it holds is not run again; commit it between "
                                                    "sittings to spread a full run over several machines")
    parser.add_argument("--workers", type=int, default=1, help="jobs run at a time: N shard processes (--threads each) "
                                                               "fill the ledger, then this one builds the tables "
                                                               "(default 1)")
    parser.add_argument("--shard", type=_shard, default=(0, 1), metavar="I/N",
                        help="one of N processes sharing --ledger (what --workers starts): it runs each job the "
                             "ledger does not hold and no other shard on this machine is running, starting from "
                             "source I of N; no --out: its tables are partial")
    args = parser.parse_args(argv)
    if args.list:
        for name in SUITES:
            suite = load(name)
            print(f"{name:18s} {suite.DESCRIPTION}\n{'':18s} full: {suite.BUDGET['full']['ours']}; paper: "
                  f"{suite.BUDGET['full']['paper']}; {suite.BUDGET['full']['expected_wall']} on 2 cores")
        return 0
    if args.suite is None:
        parser.error("name a suite (or --list)")
    if args.out is not None and args.out.suffix != ".json":
        parser.error(f"--out {args.out}: expected a .json path")
    if args.workers < 1:
        parser.error(f"--workers {args.workers}: expected at least 1")
    if (args.workers > 1 or args.shard[1] > 1) and not getattr(load(args.suite), "SHARDS", False):
        parser.error(f"--workers / --shard: suite {args.suite} has no independent fit jobs to share out")
    if args.shard[1] > 1 and (args.ledger is None or args.out is not None or args.workers > 1):
        parser.error("--shard: needs --ledger (where its jobs go), and takes neither --out nor --workers")
    repeats = args.repeats or (3 if args.quick else 7)
    with tempfile.TemporaryDirectory(prefix="neumat-bench-") as tmp:
        ledger = args.ledger or (Path(tmp) / "ledger.jsonl" if args.workers > 1 else None)
        scratch = Path(tmp) / "work" if args.workers > 1 and args.work is None else None
        if args.workers > 1:
            try:
                with harness.interrupted_by_sigterm():
                    _shards(args, ledger, repeats, args.work or scratch)
            except KeyboardInterrupt:
                print(f"{args.suite}: cut off while its shards ran (stopped with it); the ledger keeps the jobs they "
                      "finished, and the same command goes on from there", file=sys.stderr)
                return 130
        run = harness.Run(load(args.suite), args.quick, args.seed, args.threads, repeats, argv, work=args.work,
                          ledger=ledger, shard=args.shard, scratch=scratch)
        doc = run.execute()
    if args.out is not None:
        doc = harness.write(doc, args.out)
    print(json.dumps(doc, indent=1) if args.json else harness.markdown(doc))
    if run.cut_off is not None:
        print(f"{args.suite}: {run.cut_off}: the results hold the tables finished before it", file=sys.stderr)
        return 130
    return 0


def _shard(text: str) -> tuple[int, int]:
    """'I/N' -> (I, N)."""
    try:
        index, count = (int(x) for x in text.split("/"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected I/N (two integers), got {text!r}") from None
    if not 0 <= index < count:
        raise argparse.ArgumentTypeError(f"expected 0 <= I < N, got {text!r}")
    return index, count


def _shards(args: argparse.Namespace, ledger: Path, repeats: int, work: Path) -> None:
    """Run the suite's jobs in `args.workers` shard processes at once, each adding its jobs to `ledger` and sharing
    `work` (what they make, e.g. generated sources, is made once); the tables are then built from the ledger (a
    shard that failed leaves its jobs to that last pass). Interrupted, it stops the shards and raises."""
    common = [args.suite, "--ledger", str(ledger.resolve()), "--seed", str(args.seed), "--threads", str(args.threads),
              "--repeats", str(repeats), "--work", str(work.resolve())] + (["--quick"] if args.quick else [])
    shards = [subprocess.Popen([sys.executable, "-m", "benchmarks", *common, "--shard", f"{i}/{args.workers}"],
                               cwd=harness.ROOT, stdout=subprocess.DEVNULL) for i in range(args.workers)]
    try:
        for i, shard in enumerate(shards):
            if shard.wait():
                print(f"shard {i}/{args.workers} exited with status {shard.returncode}: this process runs what it "
                      "left", file=sys.stderr)
    except KeyboardInterrupt:  # stop the shards too (each keeps its finished jobs in the ledger)
        for shard in shards:
            shard.terminate()
        for shard in shards:
            shard.wait()
        raise


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
