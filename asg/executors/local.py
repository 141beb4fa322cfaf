"""``--executor local``: worker processes on this machine (one worker: this process).

Workers are started fresh (``spawn``), build their state once and ignore Ctrl-C (the parent
decides); SIGTERM makes a worker unwind, so its half-written files are removed. A worker that dies
(killed, out of memory) breaks the pool: the items that had not finished run again on a new pool;
if no item finishes between MAX_ATTEMPTS breaks in a row, the batch stops with WorkerLost.
"""
from __future__ import annotations

import multiprocessing
import os
import signal
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from typing import Any, Iterator, Sequence

from ..registry import register
from .base import MAX_ATTEMPTS, Executor, Job, WorkerLost, apply_threads

_STATE: Any = None
#: is this worker inside an item (which may hold temporary files) rather than starting or idle?
_BUSY = False


def _worker_init(threads: int, job: Job) -> None:
    global _STATE
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, _exit_on_sigterm)
    apply_threads(threads)
    _STATE = job.setup(*job.setup_args)


def _exit_on_sigterm(signum, frame) -> None:
    if _BUSY:
        raise SystemExit(143)  # unwinds: context managers remove the item's temporary files
    os._exit(143)  # starting or idle: nothing to clean up, and no traceback from the pool's machinery


def _worker_run(job: Job, item: Any) -> Any:
    global _BUSY
    _BUSY = True
    try:
        return job.run(_STATE, item)
    finally:
        _BUSY = False


@register("executor", "local")
class LocalExecutor(Executor):
    """``workers`` processes (or this process alone when ``workers`` is 1)."""

    def map_unordered(self, job: Job, items: Sequence[Any]) -> Iterator[tuple[Any, Any]]:
        if self.workers == 1:
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
                    yield item, job.run(state, item)
            finally:
                torch.set_num_threads(before[0])
                world.set_cast_threads(before[1])

    def _one_pool(self, job: Job, pending: dict[int, Any]):
        """Run ``pending`` on a new pool; yields results; returns (indices finished, pool broke)."""
        pool = ProcessPoolExecutor(max_workers=min(self.workers, len(pending)),
                                   mp_context=multiprocessing.get_context("spawn"),
                                   initializer=_worker_init, initargs=(self.threads, job))
        futures = {pool.submit(_worker_run, job, item): i for i, item in pending.items()}
        finished: list[int] = []
        broken = False
        try:
            todo = set(futures)
            while todo:
                done, todo = wait(todo, return_when=FIRST_COMPLETED)
                for fut in done:
                    try:
                        result = fut.result()
                    except BrokenProcessPool:
                        broken = True
                        continue
                    finished.append(futures[fut])
                    yield pending[futures[fut]], result
                if broken:
                    break
        finally:
            _stop(pool)
        return finished, broken


def _stop(pool: ProcessPoolExecutor) -> None:
    """Cancel what has not started and stop the workers (SIGTERM: they clean up, then exit)."""
    procs = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for p in procs:
        if p.is_alive():
            p.terminate()
    for p in procs:
        p.join(timeout=30)
