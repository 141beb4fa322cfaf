"""``--executor ray``: one Ray actor per worker, on an existing cluster (``--address``) or a local
Ray instance started for the batch.

Ray is an optional extra (``pip install 'asg[ray]'``). Each actor builds its state once and takes
one item at a time; Ray restarts an actor whose process dies and retries its task (at most
MAX_ATTEMPTS times, then the batch stops with WorkerLost). Workers get this process's import
path, so a detector factory importable here is importable there.

Signals: ``ray.init`` puts its own SIGTERM handlers in place (Abseil's failure handler, which
aborts the process 3 s after a SIGTERM with a stack dump, and a Python one that exits 15); the
Python one is kept out, a signal that arrives while Ray starts is held (``signals_deferred``) and
this process's handlers are put back once Ray has started; the driver waits for results in short
slices, each with signals held (a handler's exception inside Ray's C++ wait is lost). So SIGTERM or Ctrl-C ends a Ray
batch as it ends a local one (asg.cli: "terminated", exit 143; "interrupted", 130).
"""
from __future__ import annotations

import contextlib
import os
import signal
import sys
from typing import Any, Iterator, Sequence

from sumo_scenarios.errors import InputError

from ..interrupts import raise_if_taken
from .base import EXECUTORS, MAX_ATTEMPTS, Executor, Job, WorkerLost, apply_threads, signals_deferred
from .fatal_signals import fatal_handlers_kept, restore_fatal_handlers


class _Worker:
    """The actor: a worker's state, built once."""

    def __init__(self, threads: int, job: Job):
        apply_threads(threads)
        self.job = job
        self.state = job.setup(*job.setup_args)

    def run(self, item: Any) -> Any:
        return self.job.run(self.state, item)


#: seconds to wait for a cluster's port to answer (Ray itself retries for minutes)
PROBE_TIMEOUT_S = 5.0
#: longest an interrupted batch waits for its killed actors to be gone
KILL_WAIT_S = 10.0
#: longest the driver waits for a result at a time (a signal is handled between two waits)
WAIT_SLICE_S = 0.5


def _probe(address: str) -> None:
    """InputError unless ``address`` ("host:port", "ray://host:port" or "auto") answers on TCP."""
    import socket

    if address == "auto":
        return
    host, _, port = address.split("://")[-1].rpartition(":")
    if not host or len(host) > 253 or not (port.isascii() and port.isdigit() and 0 < int(port) < 65536):
        shown = address if len(address) <= 80 else address[:80] + "..."
        raise InputError(f"--address {shown!r} is not host:port with a port of 1-65535 (e.g. 10.0.0.5:6379)")
    try:
        socket.create_connection((host, int(port)), timeout=PROBE_TIMEOUT_S).close()
    except OSError as exc:
        raise InputError(f"the Ray cluster at {address} does not answer ({exc.strerror or exc}); "
                         f"check --address and that 'ray start --head' runs there") from None


def _import_ray():
    try:
        import ray
    except ImportError:
        raise InputError("--executor ray needs Ray, which is not installed; pip install 'asg[ray]'") from None
    return ray


@contextlib.contextmanager
def _ray_leaves_sigterm_alone(ray):
    """While inside: ``ray.init`` does not replace this process's SIGTERM handler with its own
    (which exits 15, and whose exception an at-fork hook swallows when the signal comes while Ray
    forks its node's processes). Ray's private helper; if a Ray release lacks it, nothing changes."""
    utils = getattr(getattr(ray, "_private", None), "utils", None)
    original = getattr(utils, "set_sigterm_handler", None)
    if original is None:
        yield
        return
    utils.set_sigterm_handler = lambda handler: None
    try:
        yield
    finally:
        utils.set_sigterm_handler = original


@EXECUTORS.register("ray")
class RayExecutor(Executor):
    """``workers`` Ray actors of ``threads`` CPUs each."""

    takes_address = True

    def __init__(self, workers: int = 1, threads: int = 1, address: str | None = None, idle_cores: bool = True):
        super().__init__(workers, threads, address, idle_cores)
        self.ray = _import_ray()
        self._started = False
        self._fatal_handlers: dict = {}

    def connect(self) -> None:
        """Join the cluster (or start the local instance) now; map_unordered does it when needed."""
        ray = self.ray
        if ray.is_initialized():
            return
        if self.address:
            _probe(self.address)
        env = {"env_vars": {"PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}}
        took_sigterm = False
        # Ray puts Abseil's failure handler on SIGSEGV & co. and leaves SIG_DFL at shutdown: the
        # process's own handlers (faulthandler's, for one) are put back now and after shutdown
        with fatal_handlers_kept() as self._fatal_handlers, signals_deferred() as arrived, _ray_leaves_sigterm_alone(ray):  # Ray forks its node's processes here
            try:
                if self.address:
                    ray.init(address=self.address, runtime_env=env, log_to_driver=False, logging_level="ERROR")
                else:
                    ray.init(num_cpus=self.workers * self.threads, runtime_env=env, include_dashboard=False,
                             log_to_driver=False, logging_level="ERROR")
                self._started = True
                if arrived:
                    signal.alarm(0)  # Abseil's handler took the SIGTERM too and set an abort 3 s later
            except SystemExit as exc:  # Ray's own SIGTERM handler, in place while Ray starts, took one
                if exc.code != signal.SIGTERM:
                    raise
                took_sigterm = True
            except Exception as exc:  # Ray raises ConnectionError, RuntimeError, ValueError ... for a bad address
                first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
                where = f"the Ray cluster at {self.address}" if self.address else "a local Ray instance"
                raise InputError(f"could not connect to {where} ({first[:160]}); check --address") from None
        if took_sigterm:  # handled as any SIGTERM is, by this process's own handler
            self._shutdown()
            signal.raise_signal(signal.SIGTERM)

    def map_unordered(self, job: Job, items: Sequence[Any]) -> Iterator[tuple[Any, Any]]:
        ray = self.ray
        self.connect()
        actor_cls = ray.remote(num_cpus=self.threads, max_restarts=MAX_ATTEMPTS,
                               max_task_retries=MAX_ATTEMPTS)(_Worker)
        actors = [actor_cls.remote(self.threads, job) for _ in range(min(self.workers, len(items)))]
        queue = list(enumerate(items))
        running: dict[Any, tuple[int, Any]] = {}
        idle = list(actors)
        try:
            while queue or running:
                while idle and queue:
                    actor = idle.pop()
                    i, item = queue.pop(0)
                    running[actor.run.remote(item)] = (actor, i)
                ready: list = []
                while not ready:  # in slices: a signal is handled between two, not inside Ray's C++ wait
                    with signals_deferred():  # (a handler's exception there becomes a SystemError)
                        ready, _ = ray.wait(list(running), num_returns=1, timeout=WAIT_SLICE_S)
                raise_if_taken()
                ref = ready[0]
                actor, i = running.pop(ref)
                try:
                    result = ray.get(ref)
                except ray.exceptions.RayActorError as exc:
                    raise WorkerLost(f"a Ray worker died {MAX_ATTEMPTS + 1} times on item {i}: {exc}") from None
                except ray.exceptions.RayTaskError as exc:
                    raise exc.as_instanceof_cause() from None
                idle.append(actor)
                yield items[i], result
        finally:
            for a in actors:
                ray.kill(a)
            if running:  # interrupted: until the killed actors are gone (no write of theirs comes later)
                ray.wait(list(running), num_returns=len(running), timeout=KILL_WAIT_S)

    def _shutdown(self) -> None:
        """``ray.shutdown()``, then this process's fatal-signal handlers as they were before Ray."""
        self.ray.shutdown()
        restore_fatal_handlers(self._fatal_handlers)

    def close(self) -> None:
        if self._started and self.ray.is_initialized():
            self._shutdown()
            self._started = False
