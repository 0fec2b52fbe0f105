"""Strict conversion between config dataclasses and plain dicts (JSON / YAML).

Field types are checked (`Literal` for choices); a field made with `bounded(default, ...)` also has its range
checked, so a config, a recipe's options and a preset are validated by one code path.
"""
from __future__ import annotations

import ast
import dataclasses
import functools
import inspect
import math
import re
import textwrap
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
        raise InputError(f"{cls.__name__}: unknown key(s) {', '.join(unknown)} "
                         f"(known: {', '.join(sorted(known)) or 'none'})")
    kwargs = {k: _coerce(hints[k], v, f"{cls.__name__}.{k}") for k, v in data.items() if k in known}
    for f in dataclasses.fields(cls):
        if f.name in kwargs:
            check_bounds(f, kwargs[f.name], f"{cls.__name__}.{f.name}")
    return cls(**kwargs)


def bounded(default: Any, *, ge: float | None = None, gt: float | None = None, le: float | None = None,
            lt: float | None = None) -> Any:
    """A dataclass field with `default` whose values must lie in the given range (checked by `config_from_dict`)."""
    return dataclasses.field(default=default, metadata={"bounds": (ge, gt, le, lt)})


def check_bounds(f: dataclasses.Field, value: Any, where: str) -> None:
    """InputError when `value` lies outside field `f`'s `bounded` range (or is not finite there)."""
    bounds = f.metadata.get("bounds")
    if bounds is None or value is None:
        return
    ge, gt, le, lt = bounds
    if not math.isfinite(value) or (ge is not None and value < ge) or (gt is not None and value <= gt) \
            or (le is not None and value > le) or (lt is not None and value >= lt):
        text = range_text(f)
        raise InputError(f"{where}: expected a value {'in ' if text[0] in '[(' else ''}{text}, got {value!r}")


def range_text(f: dataclasses.Field) -> str:
    """A field's `bounded` range as an interval ("[0, 1)", "> 0"), or "" for a field without one."""
    bounds = f.metadata.get("bounds")
    if bounds is None:
        return ""
    ge, gt, le, lt = bounds
    low = "[" + f"{ge:g}" if ge is not None else "(" + f"{gt:g}" if gt is not None else None
    high = f"{le:g}" + "]" if le is not None else f"{lt:g}" + ")" if lt is not None else None
    if low and high:
        return f"{low}, {high}"
    if low:
        return (">= " if ge is not None else "> ") + low[1:]
    return ("<= " if le is not None else "< ") + high[:-1]


@functools.cache
def field_docs(cls: type) -> dict[str, str]:
    """{field name: first sentence of its attribute docstring} of a dataclass (base classes included); "" where the
    source is unavailable or a field has none."""
    docs: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        if not dataclasses.is_dataclass(klass):
            continue
        try:
            tree = ast.parse(textwrap.dedent(inspect.getsource(klass)))
        except (OSError, TypeError, SyntaxError):
            continue
        body = tree.body[0].body if tree.body and isinstance(tree.body[0], ast.ClassDef) else []
        for node, after in zip(body, body[1:]):
            if isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name) \
                    and isinstance(after, ast.Expr) and isinstance(getattr(after, "value", None), ast.Constant) \
                    and isinstance(after.value.value, str):
                text = " ".join(after.value.value.strip().split("\n\n")[0].split())
                docs[node.target.id] = re.split(r"(?<=[.!?])\s+(?=[A-Z\"(`])", text, maxsplit=1)[0]
    return docs


def type_text(tp: Any) -> str:
    """A field type as `neumat list` shows it: int, float, bool, str, one of a|b, list of int, ..."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin is typing.Literal:
        return " | ".join(str(a) for a in args)
    if origin in (typing.Union, getattr(__import__("types"), "UnionType", None)):
        return " or ".join(type_text(a) for a in args if a is not type(None)) + " or none"
    if origin in (tuple, list):
        return f"list of {type_text(args[0]) if args else 'any'}"
    return getattr(tp, "__name__", str(tp))


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
    if origin is typing.Literal:
        if isinstance(v, bool) or v not in args:
            raise InputError(f"{where}: expected one of {', '.join(repr(a) for a in args)}, got {v!r}")
        return v
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
