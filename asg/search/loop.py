"""The one search loop: ask → project onto Q's members not evaluated yet → evaluate → tell,
keeping the history and the best."""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..interrupts import raise_if_taken
from .optimizer import Optimizer
from .space import FeasibleSet, nearest_index

#: evaluates a batch of normalised perturbations (each (D,)): (loss, AP by threshold) of each, in order
Objective = Callable[[list[np.ndarray]], list[tuple[float, dict[str, float]]]]


@dataclass(frozen=True)
class Evaluation:
    step: int
    x: np.ndarray
    loss: float
    ap: dict[str, float]
    optimizer_s: float


def run_search(optimizer: Optimizer, feasible: FeasibleSet, objective: Objective, budget: int,
               start: Evaluation | None = None, on_step: Callable[[Evaluation], None] | None = None,
               batched: bool = True) -> list[Evaluation]:
    """``budget`` evaluations; ``start`` (the unperturbed scene) is told first and not counted.

    Each step evaluates a member of Q (``feasible.members``, (K, D)) not evaluated before: the one
    nearest to the optimiser's ask among the fresh members, which the optimiser also gets as its
    candidates. The detector is deterministic, so a repeated member would spend an evaluation on a
    known loss (on the 30-scene benchmark, 7-21% of the asks once projected onto a member already seen).
    Once every member has been evaluated, members may repeat.

    ``batched``: ask as many members as the optimiser is ready to propose (``Optimizer.ready``), have
    ``objective`` evaluate them as one batch, then tell each in the order asked; otherwise one at a
    time. An optimiser whose proposals a tell does not change (random search, a GA's generation,
    BO's random start) proposes the same members either way."""
    members = np.asarray(feasible.members, dtype=float)
    fresh = np.ones(len(members), dtype=bool)
    history: list[Evaluation] = []
    if start is not None:
        optimizer.tell(start.x, start.loss)
        fresh &= ~np.all(members == np.asarray(start.x)[None], axis=1)
    while len(history) < budget:
        raise_if_taken()  # a signal swallowed inside the last evaluation ends the search here
        t0 = time.perf_counter()
        count = min(optimizer.ready(), budget - len(history)) if batched else 1
        xs = []
        for _ in range(count):
            rows = np.flatnonzero(fresh) if fresh.any() else np.arange(len(members))
            candidates = members[rows]
            i = int(rows[nearest_index(candidates, optimizer.ask(candidates))])
            fresh[i] = False
            xs.append(members[i])
        t_ask = (time.perf_counter() - t0) / count
        for x, (loss, ap) in zip(xs, objective(xs), strict=True):
            t1 = time.perf_counter()
            optimizer.tell(x, loss)
            ev = Evaluation(len(history) + 1, x, loss, ap, t_ask + time.perf_counter() - t1)
            history.append(ev)
            if on_step:
                on_step(ev)
    return history


def best_of(history: list[Evaluation], start: Evaluation | None = None) -> Evaluation:
    """The lowest-loss evaluation (the first of ties); the start if nothing beat it."""
    cands = ([start] if start is not None else []) + history
    return min(cands, key=lambda e: (e.loss, e.step))
