
"""The black-box optimisers' ask/tell interface; each optimiser is one file of this package,
registered by name (``asg.search.SEARCHES``).

All work in normalised units x in [-1, 1]^D and minimise the loss. ``ask`` gets the candidates, the
members of the feasible set Q not evaluated yet (K, D), and returns a point; the search loop
evaluates the candidate nearest to it, and ``tell`` receives that point. ``ready`` says how many
asks may come in a row before a tell: the search loop asks that many, has them evaluated as one
batch, then tells each (an optimiser that proposes one point at a time says 1).
"""
from __future__ import annotations

import inspect
from abc import ABC, abstractmethod

import numpy as np

from sumo_scenarios.errors import InputError

from ..registry import Registry


#: the most points a batched optimiser proposes before their losses are told (its ``batch`` setting)
MAX_BATCH = 64


def checked_batch(name: str, batch) -> int:
    """``batch`` of configs/search/NAME.yaml, a whole number in [1, MAX_BATCH]; InputError otherwise."""
    if not isinstance(batch, int) or isinstance(batch, bool) or not 1 <= batch <= MAX_BATCH:
        raise InputError(f"configs/search/{name}.yaml: batch must be a whole number in [1, {MAX_BATCH}], got {batch!r}")
    return batch


class Optimizer(ABC):
    registry_name: str = ""

    def __init__(self, dim: int, budget: int, rng: np.random.Generator):
        self.dim = dim
        self.budget = budget
        self.rng = rng

    @classmethod
    def settings(cls) -> tuple[str, ...]:
        """The keyword settings the constructor takes (configs/search/NAME.yaml)."""
        skip = {"self", "dim", "budget", "rng"}
        return tuple(n for n, p in inspect.signature(cls.__init__).parameters.items()
                     if n not in skip and p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY))

    @abstractmethod
    def ask(self, candidates: np.ndarray) -> np.ndarray:
        """A point (D,) in [-1, 1]^D; ``candidates`` (K, D), K >= 1, are Q's fresh members."""

    @abstractmethod
    def tell(self, x: np.ndarray, loss: float) -> None: ...

    def ready(self) -> int:
        """How many asks may come before the next tell (at least 1): the points it would propose
        one at a time with a tell after each, proposed before the tells (random search, a GA's
        generation, BO's random start), or the batch a batched optimiser proposes by design."""
        return 1

    def _uniform_pick(self, candidates: np.ndarray) -> np.ndarray:
        """One of the candidates (K, D), uniformly."""
        return candidates[int(self.rng.integers(len(candidates)))]


#: the search algorithms (``--search``), one module of this package each, filled by asg.search's import
SEARCHES: "Registry[type[Optimizer]]" = Registry("search algorithm", "--search")


def check_settings(name: str, params: dict) -> None:
    """InputError naming the first setting the optimiser ``name`` does not take."""
    known = SEARCHES.entry(name).settings()
    unknown = sorted(set(params) - set(known))
    if unknown:
        raise InputError(f"configs/search/{name}.yaml: unknown setting '{unknown[0]}' for {name}; "
                         f"known: {', '.join(sorted(known)) or 'none'}")


def build_optimizer(name: str, dim: int, budget: int, rng: np.random.Generator, **params) -> Optimizer:
    check_settings(name, params)
    return SEARCHES.entry(name)(dim, budget, rng, **params)
