"""Executors: run a batch of independent items on N workers, each holding its own state.

A batch is a :class:`Job`: ``setup(*args)`` builds a worker's state once (the detectors, a
generator), ``run(state, item)`` computes one item. Both must be importable top-level functions
(workers are fresh processes). Every worker runs with ``threads`` threads (torch's intra-op
threads and the LiDAR's cast threads); one thread per worker is the default because a result then
does not depend on how many workers ran the batch (torch's float sums change in the last bits with
the thread count).

Executors are registered by name (``local``, ``ray``): ``build_executor(name, workers, ...)``.
"""
from __future__ import annotations

import contextlib
import os
import signal
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any, Callable, Iterator, Sequence

from sumo_scenarios.errors import InputError

from ..registry import Registry

#: how often one item may take its worker down before the batch gives up on it
MAX_ATTEMPTS = 3


@dataclass(frozen=True)
class Job:
    """``setup(*setup_args) -> state`` once per worker, then ``run(state, item) -> result`` per item."""

    setup: Callable[..., Any]
    run: Callable[[Any, Any], Any]
    setup_args: tuple = field(default_factory=tuple)


class WorkerLost(Exception):
    """An item took its worker down (killed, crashed) more than MAX_ATTEMPTS times."""


class Executor(ABC):
    """Runs a job's items on ``workers`` workers of ``threads`` threads each."""

    registry_name: str = ""
    #: does it connect to a cluster at an ``--address``?
    takes_address: bool = False

    def __init__(self, workers: int = 1, threads: int = 1, address: str | None = None, idle_cores: bool = True):
        """``idle_cores``: may a worker score a search's candidates on the cores the workers leave
        idle (:meth:`spare_threads`)? Off, each worker keeps to its ``threads``."""
        if not isinstance(workers, int) or workers < 1:
            raise InputError(f"--workers must be at least 1, got {workers}")
        if not isinstance(threads, int) or threads < 1:
            raise InputError(f"threads per worker must be at least 1, got {threads}")
        self.workers = workers
        self.threads = threads
        self.address = address
        self.idle_cores = idle_cores

    @abstractmethod
    def map_unordered(self, job: Job, items: Sequence[Any]) -> Iterator[tuple[Any, Any]]:
        """Yield ``(item, result)`` as items finish, in any order. An item whose worker dies is
        retried on a fresh worker (at most MAX_ATTEMPTS times, then WorkerLost); an exception
        raised by ``run`` propagates."""

    def spare_threads(self, items: int) -> int:
        """The threads each worker may score a search's candidates on (asg.generator.candidates)
        when ``items`` items run: 1 unless it knows the cores its workers leave idle."""
        return 1

    @property
    def in_process(self) -> bool:
        """Does the job run in this process (so that its setup may take callables that do not
        pickle, such as a progress callback)?"""
        return False

    def close(self) -> None:
        """Release the workers (called when the batch is done)."""

    def __enter__(self) -> "Executor":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


#: the executors (``--executor``), one module of this package each, filled by its import
EXECUTORS: "Registry[type[Executor]]" = Registry("executor", "--executor")


#: libraries whose warnings are notes to their own developers, not to a user of asg (torch's beta
#: and serialisation notices, numpy's casts, shapely's and matplotlib's overflow notes): kept off a
#: successful run's stderr, in the command's process and in its workers
THIRD_PARTY_WARNINGS = r"(torch|numpy|scipy|shapely|matplotlib|sklearn|skopt|trimesh|numba|nevergrad|pygame|gymnasium)(\.|$)"


def quiet_third_party_warnings() -> None:
    """Ignore warnings raised from the modules of THIRD_PARTY_WARNINGS (asg's own still show)."""
    import warnings

    warnings.filterwarnings("ignore", module=THIRD_PARTY_WARNINGS)
    # torch's C++ notices name the Python line that called the op, not torch: known by their text
    warnings.filterwarnings("ignore", message=r"(?s).*Triggered internally at")


def apply_threads(threads: int) -> None:
    """Limit this process to ``threads`` threads: torch's, the LiDAR casts' and the OpenMP pools';
    BLAS (numpy, scipy, scikit-optimize's GP) to one thread (see :func:`blas_on_one_thread`)."""
    from threadpoolctl import threadpool_limits

    from ..sensors.world import set_cast_threads

    import torch

    set_cast_threads(threads)
    torch.set_num_threads(threads)
    threadpool_limits(limits={"openmp": threads, "blas": 1})


@contextlib.contextmanager
def blas_on_one_thread() -> Iterator[None]:
    """A context in which the loaded BLAS libraries (OpenBLAS under numpy and scipy) use one
    thread. Their matrices here are small (the GP of BO holds at most a budget of points), and
    OpenBLAS's spinning threads fight torch's OpenMP threads for the cores: a scene of AttFuse +
    ACS-A + BO took 4.3 s in one process on two threads, 2.5-2.7 s with BLAS on one (measured with
    ``asg bench generate``). torch's thread count is the same after it as before."""
    import torch
    from threadpoolctl import threadpool_limits

    import scipy.linalg  # noqa: F401  (load scipy's own OpenBLAS, so that the limit reaches it)

    torch_threads = torch.get_num_threads()
    try:
        with threadpool_limits(limits=1, user_api="blas"):
            yield
    finally:
        # putting a BLAS library back to its own count sets OpenMP's, which torch reads as its own:
        # the process left on two threads after a scene ran on one (a later scene's numbers then
        # depended on what ran before it)
        torch.set_num_threads(torch_threads)


def usable_cores() -> int:
    """The cores this process may run on (its CPU affinity where the system says)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def default_workers(items: int) -> int:
    """One worker per core, no more than there are items."""
    return max(1, min(os.cpu_count() or 1, items))


def build_executor(name: str, workers: int, threads: int = 1, address: str | None = None,
                   idle_cores: bool = True) -> Executor:
    """The executor registered as ``name``; InputError naming the known ones on a miss."""
    entry = EXECUTORS.entry(name)
    if address is not None and not entry.takes_address:
        clusters = " or ".join(n for n in EXECUTORS.names() if EXECUTORS.entry(n).takes_address)
        raise InputError(f"--address applies to --executor {clusters} only")
    return entry(workers=workers, threads=threads, address=address, idle_cores=idle_cores)


@contextlib.contextmanager
def signals_deferred():
    """SIGINT and SIGTERM that arrive inside the block take effect when it ends (main thread only),
    through the handlers in place before it (also when the block replaced them): workers start
    whole (a signal taken while a process forks can be swallowed by an at-fork hook, and a spawned
    worker half-started prints a traceback). Yields the list of signals that arrived so far."""
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield []
        return
    arrived: list[int] = []
    previous = {sig: signal.signal(sig, lambda signum, frame: arrived.append(signum))
                for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield arrived
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, signal.SIG_DFL if handler is None else handler)
        if arrived:
            signal.raise_signal(arrived[0])
