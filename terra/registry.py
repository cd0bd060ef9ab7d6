"""One registry shape for every extension point: dataset loaders, perception backends, text embedders.

Built-in entries are listed as lazy "module:attribute" strings, so looking a name up imports only
that module (and `import terra` stays cheap). Plugins from other packages join through Python entry
points of the registry's group (e.g. `[project.entry-points."terra.datasets"]`), read once on first
use. `get` of an unknown name raises a TerraError that lists the names there are.
"""

from __future__ import annotations

import importlib
from importlib.metadata import entry_points
from typing import Generic, TypeVar, cast

from terra.errors import TerraError

T = TypeVar("T")


class Registry(Generic[T]):
    """Named entries of one kind (`kind` is used in messages, `group` is the entry-point group)."""

    def __init__(self, kind: str, group: str, builtins: dict[str, str] | None = None) -> None:
        self.kind = kind
        self.group = group
        self._lazy: dict[str, str] = dict(builtins or {})
        self._loaded: dict[str, T] = {}
        self._order: list[str] = list(self._lazy)  # registration order (auto-detection tries it)
        self._discovered = False

    def register(self, name: str, entry: T | str) -> None:
        """Add (or replace) `name`: the entry itself, or a lazy "module:attribute" reference."""
        self._loaded.pop(name, None)
        self._lazy.pop(name, None)
        if name not in self._order:
            self._order.append(name)
        if isinstance(entry, str):
            self._lazy[name] = entry
        else:
            self._loaded[name] = entry

    def names(self) -> list[str]:
        """Every registered name, sorted."""
        self._discover()
        return sorted(self._order)

    def __contains__(self, name: str) -> bool:
        return name in self.names()

    def get(self, name: str) -> T:
        """The entry registered as `name`; TerraError listing the known names otherwise."""
        self._discover()
        if name not in self._loaded:
            if name not in self._lazy:
                raise TerraError(f"unknown {self.kind} {name!r}; expected one of: {', '.join(self.names())}")
            # A lazy reference names an entry of this registry's kind; only its use can check that.
            self._loaded[name] = cast(T, _resolve(self._lazy.pop(name)))
        return self._loaded[name]

    def items(self) -> list[tuple[str, T]]:
        """(name, entry) for every entry: built-ins in their listed order, then plugins."""
        self._discover()
        return [(name, self.get(name)) for name in list(self._order)]

    def _discover(self) -> None:
        if self._discovered:
            return
        self._discovered = True
        for point in entry_points(group=self.group):
            if point.name not in self._order:
                self._lazy[point.name] = point.value
                self._order.append(point.name)


def _resolve(reference: str) -> object:
    module, _, attribute = reference.partition(":")
    target: object = importlib.import_module(module)
    for part in attribute.split(".") if attribute else []:
        target = getattr(target, part)
    return target
