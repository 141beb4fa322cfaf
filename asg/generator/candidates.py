"""A search's batch of candidates scored on several threads, one torch thread each.

On these CPUs a detector's network runs faster as several single-threaded copies side by side
than as one pass over the stacked frames or one frame on several threads (AttFuse, 8 frames on
two cores: 28 ms a frame on two intra-op threads one frame at a time, 28-32 ms stacked four or
eight to a pass, 19-20 ms two frames at once on one thread each; docs/results/speed.md). A
frame's detections on one torch thread are the same bits on any thread, so a batch scored here
gives what one thread scoring it frame by frame gives: the result does not depend on how many
threads score it.

The frames are rendered before (the LiDAR world moves its vehicles in place: one thread);
detection, post-processing and AP run here. torch's thread count is global to the process:
each scoring thread sets one, and the caller's count is put back after each batch.
"""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from typing import Callable, Sequence, TypeVar

Item = TypeVar("Item")
Result = TypeVar("Result")


class CandidateThreads:
    """``threads`` threads (1: none, the caller's thread scores) that map a function over a batch.
    Started at the first batch of more than one item; ``close`` stops them."""

    def __init__(self, threads: int = 1):
        if not isinstance(threads, int) or threads < 1:
            raise ValueError(f"candidate threads must be a whole number >= 1, got {threads!r}")
        self.threads = threads
        self._pool: ThreadPoolExecutor | None = None

    def map(self, fn: Callable[[Item], Result], items: Sequence[Item]) -> list[Result]:
        """``[fn(item) for item in items]``, in order, the items spread over the threads."""
        if self.threads == 1 or len(items) < 2:
            return [fn(item) for item in items]
        import torch

        caller_threads = torch.get_num_threads()

        def on_one_thread(item: Item) -> Result:
            torch.set_num_threads(1)
            return fn(item)

        try:
            return list(self._started().map(on_one_thread, items))
        finally:
            # torch's count is the process's: the caller's comes back once the batch is scored
            # (put back before the threads' first batch, the caller's next passes ran on one)
            torch.set_num_threads(caller_threads)

    def _started(self) -> ThreadPoolExecutor:
        if self._pool is None:
            from ..perception.numerics import flush_subnormals_in_all_threads

            # the mode is per thread (asg.perception.numerics)
            self._pool = ThreadPoolExecutor(self.threads, thread_name_prefix="asg-candidate",
                                            initializer=flush_subnormals_in_all_threads)
        return self._pool

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None
