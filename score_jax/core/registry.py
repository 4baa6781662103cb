"""A name -> object registry whose entries may be ``"module:attribute"`` strings imported on
first use, so listing or importing a registry never imports every entry (the environment
registry never imports MuJoCo, the algorithm registry never imports brax)."""

from __future__ import annotations

import importlib
from typing import Generic, TypeVar

T = TypeVar("T")


class LazyRegistry(Generic[T]):
    """``register(name, obj_or_path)``; ``get(name)`` resolves a ``"module:attribute"`` entry."""

    def __init__(self, kind: str, entries: dict[str, T | str] | None = None):
        self.kind = kind
        self._entries: dict[str, T | str] = dict(entries or {})

    def register(self, name: str, entry: T | str) -> None:
        """Add (or replace) ``name``; ``entry`` is the object or its ``"module:attribute"`` path."""
        if not name or not isinstance(name, str):
            raise ValueError(f"a {self.kind} name must be a non-empty string, got {name!r}")
        if isinstance(entry, str) and entry.count(":") != 1:
            raise ValueError(
                f"a lazy {self.kind} entry must look like 'module:attribute', got {entry!r}"
            )
        self._entries[name] = entry

    def names(self) -> list[str]:
        return sorted(self._entries)

    def __contains__(self, name: object) -> bool:
        return name in self._entries

    def get(self, name: str) -> T:
        """The entry called ``name`` (imported on first use); a ValueError lists the known names."""
        if name not in self._entries:
            raise ValueError(f"unknown {self.kind} {name!r}; known: {self.names()}")
        entry = self._entries[name]
        if isinstance(entry, str):
            module, attribute = entry.split(":")
            entry = getattr(importlib.import_module(module), attribute)
            self._entries[name] = entry
        return entry
