"""`neumat bench`: the benchmark suite (`python -m benchmarks` of the source repository) from the command line."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import typer

from ..core.errors import InputError
from .common import run_command


def register(app: typer.Typer) -> None:
    app.command("bench")(bench)


def benchmarks_root() -> Path:
    """The source repository holding `benchmarks/` (beside `src/`); InputError when this install has none."""
    root = Path(__file__).resolve().parents[3]
    if not (root / "benchmarks" / "__main__.py").is_file():
        raise InputError("neumat bench: the benchmark suite ships with the source repository (benchmarks/ beside "
                         "src/); this install has none: clone the repository and `pip install -e .` it")
    return root


def bench(suite: str = typer.Argument(None, help="the suite to run (--list names them), or compare"),
          files: list[Path] = typer.Argument(None, help="compare: the committed results JSON and a rerun's"),
          list_: bool = typer.Option(False, "--list", help="name every suite with its budget, and exit"),
          quick: bool = typer.Option(False, "--quick", help="the seconds-long smoke version of the suite"),
          json_: bool = typer.Option(False, "--json", help="print the results JSON instead of the Markdown"),
          out: Path = typer.Option(None, "--out", help="write the results JSON (and its folder's README.md) here"),
          seed: int = typer.Option(0, help="seed of every fit and query set"),
          threads: int = typer.Option(1, "--threads", min=1, help="CPU threads (default 1)"),
          work: Path = typer.Option(None, "--work", help="keep the suite's fits here: the same command again "
                                                         "resumes (full runs longer than a sitting)"),
          ledger: Path = typer.Option(None, "--ledger", help="a JSON-lines file of finished fits: added to as each "
                                                             "ends, not fitted again; commit it between sittings"),
          workers: int = typer.Option(1, "--workers", min=1, help="fits run at a time, in shard processes (default "
                                                                  "1)"),
          quiet: bool = typer.Option(False, "--quiet", "-q", help="no progress output (the suite's stderr)")) -> None:
    """Run a benchmark suite: JSON results naming the command, commit and machine, and a Markdown table; or
    `neumat bench compare COMMITTED.json RERUN.json`: whether a rerun's quality numbers lie within the committed
    run's seed spread (exit status 1 names what does not)."""
    def go():
        if suite == "compare" or files:
            if suite != "compare" or len(files or []) != 2:
                raise InputError("neumat bench: two files are compared (neumat bench compare COMMITTED.json "
                                 "RERUN.json); a suite takes none")
            args = ["compare", *(str(f.resolve()) for f in files)]
        else:
            args = (["--list"] if list_ else []) + ([suite] if suite else []) + (["--quick"] if quick else []) \
                + (["--json"] if json_ else []) + (["--out", str(out.resolve())] if out else []) \
                + ["--seed", str(seed), "--threads", str(threads)] \
                + (["--work", str(work.resolve())] if work else []) \
                + (["--ledger", str(ledger.resolve())] if ledger else []) \
                + (["--workers", str(workers)] if workers != 1 else [])
        done = subprocess.run([sys.executable, "-m", "benchmarks", *args], cwd=benchmarks_root(),
                              stderr=subprocess.DEVNULL if quiet else None)
        if done.returncode:
            raise typer.Exit(done.returncode)
    run_command(go)
