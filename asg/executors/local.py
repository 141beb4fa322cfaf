"""``--executor local``: worker processes on this machine (one worker: this process).

Workers are started fresh (``spawn``), build their state once and ignore Ctrl-C from their first
instruction (the parent decides; see launcher.py); SIGTERM makes a worker unwind, so its
half-written files are removed, and then exit at once (the pool's own loop would otherwise catch the
exit and wait for more work, which made a terminated batch wait 30 s a worker). Workers get SIGTERM
when their parent dies, however it dies (Linux's parent-death signal), so none lives on to write a
scene for nobody. A worker that dies (killed, out of memory) breaks the pool: the items that had not
finished run again on a new pool; if no item finishes between MAX_ATTEMPTS breaks in a row, the
batch stops with WorkerLost.
"""
from __future__ import annotations

import ctypes
import multiprocessing
import os
import shutil
import signal
import sys
import tempfile
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import Any, Iterator, Sequence

from sumo_scenarios.errors import InputError

from .. import interrupts
from .base import EXECUTORS, MAX_ATTEMPTS, Executor, Job, WorkerLost, apply_threads, usable_cores, quiet_third_party_warnings, signals_deferred
from .launcher import spawned_ignoring_sigint

_STATE: Any = None
#: is this worker inside an item (which may hold temporary files) rather than starting or idle?
_BUSY = False
#: how long a terminated worker may take to remove its temporary files before it is killed (s)
STOP_GRACE_S = 3.0


#: the process's own os._exit, taken at import: a detector call runs with os._exit refused
#: (asg.perception.plugins.guarded_call), the worker's own exits must still end it
_exit_now = os._exit


class _WorkerTerminated(BaseException):
    """SIGTERM inside an item: unwinds it (its context managers remove its temporary files)."""


def _worker_init(threads: int, job: Job, parent_pid: int, last_word_path: str) -> None:
    global _STATE
    interrupts.leave_last_word_in(last_word_path)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, _exit_on_sigterm)
    sys.unraisablehook = _unraisable_in_worker
    quiet_third_party_warnings()
    die_with_parent(parent_pid)
    apply_threads(threads)
    _STATE = job.setup(*job.setup_args)


def die_with_parent(parent_pid: int) -> None:
    """Ask Linux for SIGTERM when the parent process ends (``prctl(PR_SET_PDEATHSIG)``); exit now
    if it has already ended. Elsewhere (no prctl) the pool's own checks remain."""
    if sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(1, int(signal.SIGTERM), 0, 0, 0)  # 1 = PR_SET_PDEATHSIG
        except (OSError, AttributeError):
            pass
    if os.getppid() != parent_pid:
        _exit_now(143)


def _exit_on_sigterm(signum, frame) -> None:
    if _BUSY:
        raise _WorkerTerminated()
    _exit_now(143)  # starting or idle: nothing to clean up, and no traceback from the pool's machinery


def _unraisable_in_worker(unraisable) -> None:
    """A SIGTERM that arrived while a finaliser or a weakref callback ran (the garbage collector's):
    Python swallows the handler's _WorkerTerminated there and prints "Exception ignored in ..."
    with a traceback, and the item would go on. Exit at once instead, silently: the parent, which
    sent the signal, removes what the item half-wrote once its workers are gone. Anything else goes
    to Python's own hook."""
    if isinstance(unraisable.exc_value, _WorkerTerminated):
        _exit_now(143)
    sys.__unraisablehook__(unraisable)


def _worker_run(job: Job, item: Any) -> Any:
    global _BUSY
    _BUSY = True
    try:
        return job.run(_STATE, item)
    except _WorkerTerminated:
        _exit_now(143)  # unwound: the item's temporary files are gone; the pool must not catch this exit
    finally:
        _BUSY = False


@EXECUTORS.register("local")
class LocalExecutor(Executor):
    """``workers`` processes (or this process alone when ``workers`` is 1)."""

    @property
    def in_process(self) -> bool:
        return self.workers == 1

    def spare_threads(self, items: int) -> int:
        """The cores of this machine shared among the workers that run: a single scene on two
        cores scores its candidates on two threads; two workers on two cores, on one each (and
        every worker on its own ``threads`` when built with ``idle_cores`` off)."""
        if not self.idle_cores:
            return 1
        return max(1, usable_cores() // (max(1, min(self.workers, items)) * self.threads))

    def map_unordered(self, job: Job, items: Sequence[Any]) -> Iterator[tuple[Any, Any]]:
        if self.in_process:
            yield from self._in_process(job, items)
            return
        pending = dict(enumerate(items))
        breaks_without_progress = 0
        while pending:
            finished, broken = yield from self._one_pool(job, pending)
            for i in finished:
                pending.pop(i)
            if not broken:
                break
            breaks_without_progress = 0 if finished else breaks_without_progress + 1
            if breaks_without_progress >= MAX_ATTEMPTS:
                raise WorkerLost(f"a worker died {MAX_ATTEMPTS} times with no item finished; "
                                 f"{len(pending)} items left undone")

    def _in_process(self, job: Job, items: Sequence[Any]) -> Iterator[tuple[Any, Any]]:
        import torch
        from threadpoolctl import threadpool_limits

        from ..sensors import world

        before = (torch.get_num_threads(), world._CAST_THREADS)
        with threadpool_limits(limits={"openmp": self.threads, "blas": 1}):  # restored after
            apply_threads(self.threads)
            try:
                state = job.setup(*job.setup_args)
                for item in items:
                    interrupts.raise_if_taken()  # a signal swallowed inside the last item ends the run here
                    yield item, job.run(state, item)
            finally:
                torch.set_num_threads(before[0])
                world.set_cast_threads(before[1])

    def _one_pool(self, job: Job, pending: dict[int, Any]):
        """Run ``pending`` on a new pool; yields results; returns (indices finished, pool broke)."""
        pool = None
        finished: list[int] = []
        broken = False
        last_word = Path(tempfile.mkdtemp(prefix="asg-pool-")) / "last-word"
        try:
            # a worker half-spawned by an interrupted start would print a traceback; a Ctrl-C to the
            # group while a worker's interpreter starts would too, so workers are born ignoring it
            with signals_deferred(), spawned_ignoring_sigint():
                pool = ProcessPoolExecutor(max_workers=min(self.workers, len(pending)),
                                           mp_context=multiprocessing.get_context("spawn"),
                                           initializer=_worker_init, initargs=(self.threads, job, os.getpid(), str(last_word)))
                futures = {pool.submit(_worker_run, job, item): i for i, item in pending.items()}
            todo = set(futures)
            while todo:
                done, todo = wait(todo, return_when=FIRST_COMPLETED)
                interrupts.raise_if_taken()
                for fut in done:
                    try:
                        result = fut.result()
                    except BrokenProcessPool:
                        if last_word.is_file():  # a worker gave up on code that would not stop
                            raise InputError(last_word.read_text()) from None
                        broken = True
                        continue
                    finished.append(futures[fut])
                    yield pending[futures[fut]], result
                if broken:
                    break
        finally:
            if pool is not None:
                _stop(pool)
            shutil.rmtree(last_word.parent, ignore_errors=True)
        return finished, broken


def _stop(pool: ProcessPoolExecutor) -> None:
    """Cancel what has not started and stop the workers (SIGTERM: they clean up, then exit)."""
    procs = list((getattr(pool, "_processes", None) or {}).values())
    manager = getattr(pool, "_executor_manager_thread", None)
    pool.shutdown(wait=False, cancel_futures=True)
    for p in procs:
        if p.is_alive():
            p.terminate()
    for p in procs:
        p.join(timeout=STOP_GRACE_S)
        if p.is_alive():  # stuck in native code: cleanup is no longer worth a scheduler's kill of us all
            p.kill()
            p.join(timeout=STOP_GRACE_S)
    if manager is not None:
        # the pool's manager thread closes its wake-up pipe as it ends; Python 3.11's exit hook
        # wakes it without a lock, and one that is closing the pipe that moment made the exit
        # print "Exception ignored ... Bad file descriptor" after the command's one line
        manager.join(timeout=STOP_GRACE_S)
