"""Entry point: `python -m benchmarks --list | SUITE [--quick] [--json] [--out FILE.json] [--work DIR] [--workers N]`."""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from . import harness
from .suites import SUITES, load


def main(argv: list[str]) -> int:
    """Run one suite and print its table (or its JSON); returns the exit status."""
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
    parser.add_argument("--workers", type=int, default=1, help="fits run at a time (fit-many's Ray engine, "
                                                               "--threads each; default 1: one after another)")
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
    repeats = args.repeats or (3 if args.quick else 7)
    run = harness.Run(load(args.suite), args.quick, args.seed, args.threads, repeats, argv, work=args.work,
                      workers=args.workers)
    doc = run.execute()
    if args.out is not None:
        harness.write(doc, args.out)
    print(json.dumps(doc, indent=1) if args.json else harness.markdown(doc))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
