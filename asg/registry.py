"""Name → class registries (fusion methods, search algorithms, ...): one decorator, one lookup.

Each subpackage's ``__init__`` imports its implementations, so a registry is full once its
package is imported.
"""
from __future__ import annotations

from importlib import metadata
from typing import Callable, TypeVar

from sumo_scenarios.errors import InputError

#: the entry-point group of detectors: the shipped ones (pyproject.toml) and installed plugins
DETECTOR_ENTRY_POINTS = "asg.detectors"

T = TypeVar("T")
_REGISTRIES: dict[str, dict[str, type]] = {}


def register(kind: str, name: str) -> Callable[[type[T]], type[T]]:
    def deco(cls: type[T]) -> type[T]:
        table = _REGISTRIES.setdefault(kind, {})
        if name in table:
            raise RuntimeError(f"{kind} '{name}' registered twice")
        table[name] = cls
        cls.registry_name = name  # type: ignore[attr-defined]
        return cls

    return deco


def names(kind: str) -> list[str]:
    return sorted(_REGISTRIES.get(kind, {}))


def lookup(kind: str, name: str) -> type:
    table = _REGISTRIES.get(kind, {})
    if name not in table:
        raise InputError(f"unknown {kind} '{name}'; known: {', '.join(sorted(table)) or 'none'}")
    return table[name]


def detector_entry_names() -> list[str]:
    """Every detector name installed as an entry point (the shipped models and the plugins), read
    from the package metadata without importing a detector."""
    return sorted({ep.name for ep in metadata.entry_points(group=DETECTOR_ENTRY_POINTS)})
