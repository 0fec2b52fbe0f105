"""A typed name -> entry registry (factories, classes or data records). Duplicate names raise; unknown names raise
with close matches."""
from __future__ import annotations

import difflib
import functools
import importlib
import pkgutil
from typing import Callable, Generic, Iterator, TypeVar

from .errors import InputError, UnknownNameError

T = TypeVar("T")


class Registry(Generic[T]):
    """Maps lowercase names to factories (classes or functions) producing `T`."""

    def __init__(self, kind: str) -> None:
        self.kind = kind
        self._items: dict[str, Callable[..., T]] = {}

    def register(self, name: str) -> Callable[[Callable[..., T]], Callable[..., T]]:
        """Decorator registering a factory under `name`."""
        if name != name.lower() or not name:
            raise InputError(f"{self.kind} registry: names are lowercase and non-empty, got {name!r}")

        def deco(factory: Callable[..., T]) -> Callable[..., T]:
            if name in self._items:
                raise InputError(f"{self.kind} registry: {name!r} is already registered")
            self._items[name] = factory
            return factory

        return deco

    def get(self, name: str) -> Callable[..., T]:
        """The factory registered as `name`."""
        key = name.lower()
        if key not in self._items:
            close = difflib.get_close_matches(key, self._items, n=3, cutoff=0.5)
            hint = f"; did you mean {', '.join(close)}?" if close else ""
            raise UnknownNameError(
                f"unknown {self.kind} {name!r}{hint} (known: {', '.join(sorted(self._items)) or 'none'})")
        return self._items[key]

    def build(self, spec: dict) -> T:
        """Build from a plain dict `{"type": name, **kwargs}`."""
        if not isinstance(spec, dict) or "type" not in spec:
            raise InputError(f"{self.kind} spec must be a dict with a 'type' key, got {spec!r}")
        kwargs = {k: v for k, v in spec.items() if k != "type"}
        return self.get(spec["type"])(**kwargs)

    def __getitem__(self, name: str) -> T:
        return self.get(name)

    def names(self) -> list[str]:
        """The registered names, sorted."""
        return sorted(self._items)

    def items(self) -> list[tuple[str, Callable[..., T]]]:
        """(name, entry) pairs in registration order."""
        return list(self._items.items())

    def __len__(self) -> int:
        return len(self._items)

    def __contains__(self, name: str) -> bool:
        return name.lower() in self._items

    def __iter__(self) -> Iterator[str]:
        return iter(self.names())


@functools.cache
def import_package_modules(package: str, prefix: str = "", recursive: bool = False) -> None:
    """Import, once, every module of `package` whose name starts with `prefix` (with `recursive`, its
    subpackages' too): the modules register themselves, so a registry is complete after this call."""
    path = importlib.import_module(package).__path__
    infos = pkgutil.walk_packages(path, f"{package}.") if recursive else pkgutil.iter_modules(path, f"{package}.")
    for info in infos:
        if info.name.rsplit(".", 1)[-1].startswith(prefix):
            importlib.import_module(info.name)
