"""Helpers shared by CLI commands: clean error reporting, the console, key=value overrides, torch threads."""
from __future__ import annotations

import json
import math
import numbers
import os
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Callable

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from ..core.checks import check_device
from ..core.config import parse_value
from ..core.errors import InputError, NeumatError
from ..core.threads import shared_threads

console = Console(stderr=True)

#: help of the --threads options of `neumat fit` and `neumat fit-many`
THREADS_HELP = ("torch threads of the command, per fit where it runs several (default: the cores that other work "
                "leaves free, all when none is busy, looked at again every 10 s of a fit: a NeuBRDF-sized training "
                "step on 2 threads of 2 cores ran 16x slower beside one busy process than on 1 thread)")


def run_command(fn: Callable[[], Any]) -> Any:
    """Run `fn`, turning bad input into a one-line message and exit code 2: neumat errors, files that are
    missing, unreadable, folders or in the way (OSError), and requests larger than the memory."""
    try:
        return fn()
    except (NeumatError, FileNotFoundError) as e:
        _fail(str(e))
    except OSError as e:
        _fail(f"{e.strerror or e}: {e.filename!r}" if e.filename else str(e))
    except MemoryError:
        _fail("not enough memory for the requested sizes; choose smaller ones")
    except RuntimeError as e:  # torch's allocator reports failures as RuntimeError
        if "can't allocate memory" not in str(e) and "out of memory" not in str(e):
            raise
        _fail(f"not enough memory for the requested sizes; choose smaller ones ({str(e).splitlines()[-1][:200]})")


def _fail(message: str) -> None:
    console.print("[bold red]error:[/] " + escape(message), soft_wrap=True)  # one line: paths stay whole
    raise typer.Exit(2)


def default_device() -> str:
    """The device of every command whose --device is not given: cuda when torch sees a GPU, else cpu."""
    import torch

    return "cuda" if torch.cuda.is_available() else "cpu"


def device_option(value: str | None) -> str:
    """Typer callback of every --device option: the default device when none is given (one rule for all
    commands), and a device that does not exist here refused before any work."""
    if value is None:
        return default_device()
    try:
        check_device(value, "device")
    except InputError as e:
        raise typer.BadParameter(str(e).removeprefix("device: ")) from None
    return value


def _with_option(command: Callable, name: str, annotation: str, option, context: Callable) -> Callable:
    """`command` with one more keyword option `name` (a typer `option`), its run wrapped in `context(value)`;
    `command` itself when it already takes `name`."""
    import functools
    import inspect

    signature = inspect.signature(command)
    if name in signature.parameters:
        return command
    parameter = inspect.Parameter(name, inspect.Parameter.KEYWORD_ONLY, annotation=annotation, default=option)

    @functools.wraps(command)
    def run(*args, **kwargs):
        with context(kwargs.pop(name, option.default)):
            return command(*args, **kwargs)

    run.__signature__ = signature.replace(parameters=[*signature.parameters.values(), parameter])
    run.__annotations__ = {**command.__annotations__, name: annotation}
    return run


def with_threads(command: Callable) -> Callable:
    """`command` with a --threads option (torch's intra-op threads for its run), for commands that compute and
    do not take one themselves."""
    return _with_option(command, "threads", "int", typer.Option(None, "--threads", min=1, help=THREADS_HELP),
                        shared_threads)


@contextmanager
def _quiet_env(on: bool):
    """NEUMAT_QUIET set while the block runs, when `on`."""
    before = os.environ.get(QUIET_ENV)
    if on:
        os.environ[QUIET_ENV] = "1"
    try:
        yield
    finally:
        if on and before is None:
            os.environ.pop(QUIET_ENV, None)


def with_quiet(command: Callable) -> Callable:
    """`command` with a --quiet / -q option, for commands that compute and do not take one themselves: no progress
    output from what it runs (a fit's progress lines; `neumat.fit.trainer` reads NEUMAT_QUIET)."""
    return _with_option(command, "quiet", "bool", typer.Option(False, "--quiet", "-q", help="no progress output"),
                        _quiet_env)


#: set while a command runs with --quiet (read by the trainer's progress)
QUIET_ENV = "NEUMAT_QUIET"


def add_threads(app: typer.Typer, skip: tuple[str, ...] = ("list", "version", "info")) -> None:
    """Give every command of `app` and its sub-apps that computes (all but `skip`) a --threads and a --quiet
    option."""
    for info in app.registered_commands:
        name = info.name or info.callback.__name__.replace("_", "-")
        if name not in skip:
            info.callback = with_quiet(with_threads(info.callback))
    for group in app.registered_groups:
        add_threads(group.typer_instance, skip)


def output_option(*suffixes: str) -> Callable[[Path | None], Path | None]:
    """Typer callback of an output file option: refuse, before any work, a path that is a folder, lies under a
    file, or does not end in one of `suffixes` (".png", ...)."""
    def check(value: Path | None) -> Path | None:
        if value is None:
            return value
        if value.is_dir():
            raise typer.BadParameter(f"{str(value)!r} is a folder; expected a {'/'.join(suffixes)} file path")
        if value.suffix.lower() not in suffixes:
            raise typer.BadParameter(f"{str(value)!r}: expected a file name ending in {', '.join(suffixes)}")
        blocking = next((p for p in value.parents if p.exists() and not p.is_dir()), None)
        if blocking is not None:
            raise typer.BadParameter(f"{str(value)!r}: {str(blocking)!r} is a file, not a folder")
        return value
    return check


#: image suffixes writable by `io.images.write_image`
IMAGE_OUT = (".png", ".jpg", ".jpeg", ".exr", ".hdr")


#: the range torch.manual_seed and numpy accept, for --seed options (`typer.Option(0, **SEED_RANGE)`)
SEED_RANGE = {"min": 0, "max": 2 ** 63 - 1}


def parse_overrides(items: list[str] | None, option: str = "--set", text: bool = False) -> dict[str, Any]:
    """`["nside=32", "lr=1e-3", "betas=0.99,0.999"]` -> {"nside": 32, "lr": 0.001, "betas": [0.99, 0.999]} (a
    value with commas is a list; JSON for nested lists and null: bounds=[[0,0,0],[1,1,1]], bounds=null), or with
    `text` the values as written; `option` names the flag in errors."""
    import json

    out = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise InputError(f"{option} expects key=value, got {item!r}")
        if text:
            out[key.strip()] = value
        elif value.strip().startswith("[") or value.strip() == "null":
            try:
                out[key.strip()] = json.loads(value)
            except ValueError:
                raise InputError(f"{option} {key.strip()}: {value!r} is not a JSON list") from None
        else:
            out[key.strip()] = [parse_value(v) for v in value.split(",")] if "," in value else parse_value(value)
    return out


def print_table(title: str, rows: list[dict[str, Any]], width: int | None = None) -> None:
    """Print rows (dicts with the same keys) as a rich table on stdout, `width` characters wide (default: the
    terminal's; benchmarks writing logs pass a wide one)."""
    table = Table(title=title)
    keys = list(rows[0]) if rows else []
    for k in keys:
        table.add_column(k)
    for r in rows:
        table.add_row(*(_fmt(r[k]) for k in keys))
    Console(width=width).print(table)


def print_json(obj: Any) -> None:
    """Print one JSON object on stdout; NaN and infinite numbers (which JSON lacks) print as null."""
    print(json.dumps(_finite_or_none(obj), indent=2, default=float, allow_nan=False))


def _finite_or_none(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {k: _finite_or_none(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite_or_none(v) for v in obj]
    if isinstance(obj, numbers.Integral) or not hasattr(obj, "__float__"):
        return obj
    v = float(obj)
    return v if math.isfinite(v) else None


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)
