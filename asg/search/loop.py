"""The one search loop: ask → project onto Q → evaluate → tell, keeping the history and the best."""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from .algorithms import Optimizer
from .space import FeasibleSet

#: evaluates a normalised perturbation: returns (loss, AP by threshold)
Objective = Callable[[np.ndarray], tuple[float, dict[str, float]]]


@dataclass(frozen=True)
class Evaluation:
    step: int
    x: np.ndarray
    loss: float
    ap: dict[str, float]
    optimizer_s: float


def run_search(optimizer: Optimizer, feasible: FeasibleSet, objective: Objective, budget: int,
               start: Evaluation | None = None, on_step: Callable[[Evaluation], None] | None = None) -> list[Evaluation]:
    """``budget`` evaluations; ``start`` (the unperturbed scene) is told first and not counted."""
    history: list[Evaluation] = []
    if start is not None:
        optimizer.tell(start.x, start.loss)
    for step in range(1, budget + 1):
        t0 = time.perf_counter()
        x = feasible.project(optimizer.ask())
        t_opt = time.perf_counter() - t0
        loss, ap = objective(x)
        t1 = time.perf_counter()
        optimizer.tell(x, loss)
        ev = Evaluation(step, x, loss, ap, t_opt + time.perf_counter() - t1)
        history.append(ev)
        if on_step:
            on_step(ev)
    return history


def best_of(history: list[Evaluation], start: Evaluation | None = None) -> Evaluation:
    """The lowest-loss evaluation (the first of ties); the start if nothing beat it."""
    cands = ([start] if start is not None else []) + history
    return min(cands, key=lambda e: (e.loss, e.step))
