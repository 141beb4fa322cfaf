"""Registries: one per extension point, each owned by the package of its base class.

A registry maps a name to its entry (a class) and answers what callers need to know about the part
by asking the entry's own attributes (``needs_attention``, ``has_attention``, ``feed``, ...), never by
comparing names or classes. Each package defines its registry beside its base class and imports its
implementations in its ``__init__``, so ``from asg.search import SEARCHES`` gives a full registry:

    asg.perception.fusion.FUSIONS       the shipped detectors (``--fusion``)
    asg.search.SEARCHES                 search algorithms (``--search``)
    asg.search.spaces.SPACES            perturbation spaces (``--space``)
    asg.collaborators.ACS_STRATEGIES    collaborator searches (``--acs``)
    asg.executors.EXECUTORS             executors (``--executor``)
    asg.io.export.EXPORT_FORMATS        export formats (``asg export --format``)
    asg.benchmarks.tables.TABLE_KINDS   the paper's tables (``asg bench paper --table``), in order

Detector plugins of other packages come in through the ``asg.detectors`` entry point group
(asg.perception.plugins); the shipped models are only in FUSIONS.
"""
from __future__ import annotations

from dataclasses import dataclass
from importlib import metadata
from typing import Callable, Generic, Iterator, TypeVar

from sumo_scenarios.errors import InputError

#: the entry-point group of detector plugins (installed packages; the shipped models are in FUSIONS)
DETECTOR_ENTRY_POINTS = "asg.detectors"


@dataclass(frozen=True)
class TargetPrefix:
    """The prefix of a ``--fusion`` that names a target kind of its own (a folder of another
    framework's model), and whether that framework's runtime wants OpenMP's threads spinning."""
    prefix: str
    spins_omp: bool = False


#: target kind -> its prefix: the one place a prefix is written. The kinds themselves live in
#: asg.perception.targets (which reads them here); this table is torch-free, so that the command
#: line can act on a prefix before torch loads.
TARGET_PREFIXES = {"opencood": TargetPrefix("opencood:", spins_omp=True)}


def prefixed_kind(name: object) -> str | None:
    """The target kind whose prefix starts ``name`` (None: a shipped model's or a plugin's name)."""
    return next((kind for kind, p in TARGET_PREFIXES.items() if isinstance(name, str) and name.startswith(p.prefix)),
                None)


def wants_spinning_omp(argv) -> bool:
    """Does a command line name a target whose runtime wants OpenMP's threads spinning (anywhere in
    an argument: ``--fusion=opencood:DIR``, ``--models attfuse,opencood:DIR``)?"""
    return any(p.spins_omp and p.prefix in str(arg) for arg in argv for p in TARGET_PREFIXES.values())

T = TypeVar("T")


class Registry(Generic[T]):
    """Name -> entry of one extension point. ``what`` names the kind in messages ("search
    algorithm"); ``flag`` is the option that takes the name ("--search"); ``ordered``: the names
    in the order they were registered (a sequence that means something, as the paper's tables),
    else sorted."""

    def __init__(self, what: str, flag: str, ordered: bool = False):
        self.what = what
        self.flag = flag
        self.ordered = ordered
        self._entries: dict[str, T] = {}

    def register(self, name: str) -> Callable[[T], T]:
        """Class decorator: the entry ``name`` (its ``registry_name`` is set to it)."""
        def deco(entry: T) -> T:
            if name in self._entries:
                raise RuntimeError(f"{self.what} '{name}' registered twice")
            self._entries[name] = entry
            entry.registry_name = name  # type: ignore[attr-defined]
            return entry

        return deco

    def unregister(self, name: str) -> None:
        """Remove the entry ``name`` (a test's temporary entry)."""
        del self._entries[name]

    def names(self) -> list[str]:
        return list(self._entries) if self.ordered else sorted(self._entries)

    def __contains__(self, name: object) -> bool:
        return name in self._entries

    def __iter__(self) -> Iterator[str]:
        return iter(self.names())

    def entry(self, name: str) -> T:
        """The entry called ``name``; InputError (one line with the known names) if there is none."""
        return self._entries[self.check(name)]

    def entries(self) -> list[T]:
        return [self._entries[n] for n in self.names()]

    def check(self, name: str, extra: tuple[str, ...] = ()) -> str:
        """``name`` if it is an entry (or one of ``extra``, e.g. "off"), else the InputError every
        command refuses it with, before any work starts."""
        if name in self._entries or name in extra:
            return name
        known = ", ".join([*self.names(), *extra]) or "none"
        raise InputError(f"unknown {self.what} {safe_name(name)} for {self.flag}; known: {known}")


def import_modules(package: str, path) -> None:
    """Import every module of ``package`` (its ``__path__``): each registers its parts in the
    package's registry, so a new part is its module, with no import line to add."""
    import importlib
    import pkgutil

    for module in pkgutil.iter_modules(path):
        importlib.import_module(f"{package}.{module.name}")


def safe_name(name: object) -> str:
    """A user's name quoted for a one-line message (newlines and control characters escaped)."""
    return repr(str(name))


def detector_entry_names() -> list[str]:
    """Every detector plugin installed as an entry point, read from the package metadata without
    importing one."""
    return sorted({ep.name for ep in metadata.entry_points(group=DETECTOR_ENTRY_POINTS)})
