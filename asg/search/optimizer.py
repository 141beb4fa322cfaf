
"""The black-box optimisers' ask/tell interface; each optimiser is one file of this package,
registered by name (``asg.search.SEARCHES``).

All work in normalised units x in [-1, 1]^D and minimise the loss. ``ask`` gets the candidates, the
members of the feasible set Q not evaluated yet (K, D), and returns a point; the search loop
evaluates the candidate nearest to it, and ``tell`` receives that point.
"""
from __future__ import annotations

import inspect
from abc import ABC, abstractmethod

import numpy as np

from sumo_scenarios.errors import InputError

from ..registry import Registry


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
