"""Spec strings for scenes and lights: `NAME[:ARG][,KEY=VALUE]*`.

ARG is everything between the first ':' and the first ',' (a path, or a light's position / direction /
value). Values are numbers, `true` / `false`, RGB triples or 3-vectors written `a/b/c`, or plain words.
Examples: "sphere,camera=pinhole", "mesh:/data/bunny.ply,fov=35", "dir:0.3/0.5/0.8,irradiance=2",
"env:sky,sun_elevation=20".
"""
from __future__ import annotations

import difflib
from dataclasses import dataclass, field
from typing import Any

from ..core.config import parse_value
from ..core.errors import InputError, UnknownNameError


@dataclass
class Spec:
    """A parsed spec string: name, optional argument text, and keyword options."""

    name: str
    arg: str | None = None
    options: dict[str, Any] = field(default_factory=dict)


def parse_spec(text: str, what: str) -> Spec:
    """Split `text` into a `Spec`; `what` ("scene", "light") names the input in errors."""
    if not isinstance(text, str) or not text.strip():
        raise InputError(f"{what} spec: expected a non-empty string such as 'sphere', got {text!r}")
    head, *pairs = text.strip().split(",")
    name, sep, arg = head.partition(":")
    options = {}
    for pair in pairs:
        key, eq, value = pair.partition("=")
        if not eq or not key.strip():
            raise InputError(f"{what} spec {text!r}: expected KEY=VALUE after ',', got {pair!r}")
        options[key.strip()] = parse_option_value(value.strip())
    return Spec(name.strip().lower(), arg.strip() if sep else None, options)


def parse_option_value(text: str) -> Any:
    """A number, bool, word, or a tuple of floats for `a/b/c`."""
    if "/" in text:
        try:
            return tuple(float(x) for x in text.split("/"))
        except ValueError:
            return text
    return parse_value(text)


def check_options(options: dict, known: dict[str, str], who: str) -> None:
    """Raise for keys of `options` not in `known` (key -> one-line description)."""
    unknown = sorted(set(options) - set(known))
    if unknown:
        listing = "; ".join(f"{k}: {v}" for k, v in known.items()) or "none"
        raise InputError(f"{who}: unknown option(s) {', '.join(unknown)} (known: {listing})")


def unknown_name(what: str, name: str, known: list[str]) -> UnknownNameError:
    """An `UnknownNameError` for spec name `name`, listing the known forms and close matches."""
    bare = [k.split(":")[0] for k in known]
    close = difflib.get_close_matches(name, bare, n=3, cutoff=0.5)
    hint = f"; did you mean {', '.join(close)}?" if close else ""
    return UnknownNameError(f"unknown {what} {name!r}{hint} (known: {', '.join(known)})")


def as_vector(value: Any, who: str, size: int = 3) -> tuple[float, ...]:
    """A tuple of `size` floats from a number (repeated) or a tuple; raises for anything else."""
    if isinstance(value, bool):
        raise InputError(f"{who}: expected a number or {size} numbers a/b/c, got {value!r}")
    if isinstance(value, (int, float)):
        return (float(value),) * size
    if isinstance(value, (tuple, list)) and len(value) == size:
        try:
            return tuple(float(v) for v in value)
        except (TypeError, ValueError):
            pass
    raise InputError(f"{who}: expected a number or {size} numbers written a/b/c, got {value!r}")


def as_float(value: Any, who: str) -> float:
    """A float from a number; raises for anything else."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InputError(f"{who}: expected a number, got {value!r}")
    return float(value)
