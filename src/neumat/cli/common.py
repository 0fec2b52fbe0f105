"""Helpers shared by CLI commands: clean error reporting, the console, key=value overrides."""
from __future__ import annotations

import json
from typing import Any, Callable

import typer
from rich.console import Console
from rich.table import Table

from ..core.config import parse_value
from ..core.errors import InputError, NeumatError

console = Console(stderr=True)


def run_command(fn: Callable[[], Any]) -> Any:
    """Run `fn`, turning neumat errors and missing files into a one-line message and exit code 2."""
    try:
        return fn()
    except (NeumatError, FileNotFoundError) as e:
        console.print(f"[bold red]error:[/] {e}")
        raise typer.Exit(2) from None


def parse_overrides(items: list[str] | None, option: str = "--set", text: bool = False) -> dict[str, Any]:
    """`["nside=32", "lr=1e-3", "betas=0.99,0.999"]` -> {"nside": 32, "lr": 0.001, "betas": [0.99, 0.999]} (a
    value with commas is a list), or with `text` the values as written; `option` names the flag in errors."""
    out = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise InputError(f"{option} expects key=value, got {item!r}")
        if text:
            out[key.strip()] = value
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
    """Print one JSON object on stdout."""
    print(json.dumps(obj, indent=2, default=float))


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)
