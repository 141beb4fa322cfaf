"""Importing OpenCOOD (the ``opencoodx`` package) beside asg's pinned libraries.

Two things of opencoodx 0.1.19 do not import as shipped, and are made to, without changing its code:
- ``opencood.utils.box_overlaps`` is Cython source (``.pyx``) that its post-processor imports: it is
  compiled once with Cython (pyximport) into asg's cache folder (``$XDG_CACHE_HOME/asg/opencood``,
  default ``~/.cache/asg/opencood``), a few seconds on first use;
- its visualisation module, imported by the post-processor, calls ``matplotlib.cm.get_cmap``, which
  matplotlib 3.9 removed: the same function is put back under that name (``matplotlib.colormaps``).
"""
from __future__ import annotations

import importlib
import os
from pathlib import Path
from types import ModuleType

from sumo_scenarios.errors import InputError

#: the extra that brings OpenCOOD, as the one-line message names it
EXTRA_HINT = "pip install 'asg[opencood]'"
_READY = False


def cache_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "asg" / "opencood"


def opencood() -> ModuleType:
    """The ``opencood`` package, importable with its compiled overlaps and matplotlib shim;
    InputError (one line naming the extra) when opencoodx or one of its parts is not installed."""
    global _READY
    try:
        package = importlib.import_module("opencood")
    except ImportError:
        raise InputError(f"--fusion opencood:DIR needs OpenCOOD, which is not installed; {EXTRA_HINT}") from None
    if not _READY:
        _restore_get_cmap()
        _build_box_overlaps()
        _READY = True
    return package


def module(name: str) -> ModuleType:
    """``opencood.NAME`` imported; InputError naming what is missing (e.g. spconv) otherwise."""
    opencood()
    try:
        return importlib.import_module(f"opencood.{name}")
    except ImportError as exc:
        raise InputError(f"OpenCOOD's {name} cannot be imported here ({exc}); {EXTRA_HINT}") from None


def compute_instances_by(model, module_type: type, forward) -> list:
    """Every module of ``model`` that is a ``module_type`` computes by ``forward`` (a function of
    the module and its inputs): those instances only, OpenCOOD's class stays as shipped; returns
    them."""
    from types import MethodType

    instances = [m for m in model.modules() if isinstance(m, module_type)]
    for instance in instances:
        instance.forward = MethodType(forward, instance)
    return instances


def _restore_get_cmap() -> None:
    import matplotlib
    import matplotlib.cm

    if not hasattr(matplotlib.cm, "get_cmap"):
        matplotlib.cm.get_cmap = lambda name=None, lut=None: matplotlib.colormaps.get_cmap(name)


def _build_box_overlaps() -> None:
    """Make ``opencood.utils.box_overlaps`` importable: compiled from its .pyx unless already built."""
    try:
        importlib.import_module("opencood.utils.box_overlaps")
        return
    except ImportError:
        pass
    try:
        import numpy
        import pyximport
    except ImportError:
        raise InputError(f"OpenCOOD's box_overlaps.pyx needs Cython to build; {EXTRA_HINT}") from None
    build = cache_dir()
    try:
        build.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"{build}: OpenCOOD's compiled box_overlaps cannot be cached there ({exc.strerror}); "
                         "set XDG_CACHE_HOME to a writable folder") from None
    importers = pyximport.install(setup_args={"include_dirs": numpy.get_include()}, build_dir=str(build),
                                  language_level=3, inplace=False)
    try:
        importlib.import_module("opencood.utils.box_overlaps")
    except Exception as exc:  # a compiler error: name it in one line
        raise InputError(f"OpenCOOD's box_overlaps.pyx could not be compiled ({type(exc).__name__}); "
                         "install a C compiler (gcc) and the Python headers") from None
    finally:
        pyximport.uninstall(*importers)
