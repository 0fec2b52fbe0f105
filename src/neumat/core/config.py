"""Strict conversion between config dataclasses and plain dicts (JSON / YAML)."""
from __future__ import annotations

import dataclasses
import typing
from typing import Any, TypeVar

from .errors import InputError

C = TypeVar("C")


def config_to_dict(cfg: Any) -> dict:
    """Plain dict of a config dataclass (tuples become lists)."""
    return {f.name: _plain(getattr(cfg, f.name)) for f in dataclasses.fields(cfg)}


def config_from_dict(cls: type[C], data: dict, *, ignore: tuple[str, ...] = ("type", "neumat_version")) -> C:
    """Build `cls` from `data`. Unknown keys raise; values are checked and coerced to the field types."""
    if not isinstance(data, dict):
        raise InputError(f"{cls.__name__}: expected a dict, got {type(data).__name__}")
    hints = typing.get_type_hints(cls)
    known = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - known - set(ignore))
    if unknown:
        raise InputError(f"{cls.__name__}: unknown key(s) {', '.join(unknown)} (known: {', '.join(sorted(known))})")
    kwargs = {k: _coerce(hints[k], v, f"{cls.__name__}.{k}") for k, v in data.items() if k in known}
    return cls(**kwargs)


def resolve_config(cls: type[C], config: C | None, fields: dict, who: str) -> C:
    """The config of a model built as `Model(config)` or `Model(**fields)` (strictly parsed); both raise."""
    if config is not None and fields:
        raise InputError(f"{who}: pass either a Config or keyword fields, not both")
    if config is None:
        return config_from_dict(cls, fields)
    if not isinstance(config, cls):
        raise InputError(f"{who}: config must be a {cls.__qualname__}, got {type(config).__name__}")
    return config


def parse_value(text: str) -> Any:
    """Parse a command-line value: int, float, bool, comma-free string."""
    low = text.strip().lower()
    if low in ("true", "false"):
        return low == "true"
    for conv in (int, float):
        try:
            return conv(text)
        except ValueError:
            pass
    return text


def _plain(v: Any) -> Any:
    if isinstance(v, tuple):
        return [_plain(x) for x in v]
    if dataclasses.is_dataclass(v):
        return config_to_dict(v)
    return v


def _coerce(tp: Any, v: Any, where: str) -> Any:
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if origin in (typing.Union, getattr(__import__("types"), "UnionType", None)):
        if v is None and type(None) in args:
            return None
        errors = []
        for a in args:
            if a is type(None):
                continue
            try:
                return _coerce(a, v, where)
            except InputError as e:
                errors.append(str(e))
        raise InputError(errors[0] if errors else f"{where}: bad value {v!r}")
    if origin in (tuple, list):
        if isinstance(v, (int, float, str)) and not isinstance(v, bool) and args and args[-1] is not Ellipsis \
                and len(args) > 1:
            raise InputError(f"{where}: expected a list of {len(args)}, got {v!r}")
        if isinstance(v, (int, float, str)):  # one value where a list is expected (`--set hidden=8`)
            v = [v]
        if not isinstance(v, (list, tuple)):
            raise InputError(f"{where}: expected a list, got {v!r}")
        inner = args[0] if args else Any
        items = [_coerce(inner, x, where) for x in v]
        return tuple(items) if origin is tuple else items
    if tp is bool:
        if isinstance(v, bool):
            return v
        raise InputError(f"{where}: expected true/false, got {v!r}")
    if tp is int:
        if isinstance(v, bool) or not isinstance(v, int) and not (isinstance(v, float) and v.is_integer()):
            raise InputError(f"{where}: expected an integer, got {v!r}")
        return int(v)
    if tp is float:
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise InputError(f"{where}: expected a number, got {v!r}")
        return float(v)
    if tp is str:
        if not isinstance(v, str):
            raise InputError(f"{where}: expected a string, got {v!r}")
        return v
    return v
