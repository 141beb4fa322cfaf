
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
import math
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from sumo_scenarios import checks
from sumo_scenarios.errors import InputError

from ..registry import Registry


#: the most points a batched optimiser proposes before their losses are told (its ``batch`` setting)
MAX_BATCH = 64


@dataclass(frozen=True)
class Setting:
    """One setting of configs/search/NAME.yaml: a whole number (``int``) or a number (``float``)
    within [lo, hi] (lo excluded when ``lo_open``), or text (``str``)."""
    kind: type
    lo: float = -math.inf
    hi: float = math.inf
    lo_open: bool = False

    def check(self, value: Any, where: str) -> None:
        """InputError naming ``where`` unless ``value`` is of this kind and within range."""
        if self.kind is str:
            if not isinstance(value, str):
                raise InputError(f"{where}: expected text, got {value!r}")
            return
        if self.kind is int and (isinstance(value, bool) or not isinstance(value, int)):
            raise InputError(f"{where}: expected a whole number, got {value!r}")
        checks.number(value, where, self.lo, self.hi, lo_open=self.lo_open)


#: the ``batch`` setting of an optimiser that proposes several points before their losses are told
BATCH = Setting(int, 1, MAX_BATCH)


class Optimizer(ABC):
    registry_name: str = ""
    #: its settings (configs/search/NAME.yaml: the constructor's keywords) and their ranges
    SETTINGS: ClassVar[dict[str, Setting]] = {}

    def __init__(self, dim: int, budget: int, rng: np.random.Generator):
        self.dim = dim
        self.budget = budget
        self.rng = rng

    @classmethod
    def settings(cls) -> tuple[str, ...]:
        """The keyword settings the constructor takes (configs/search/NAME.yaml)."""
        return tuple(cls.SETTINGS)

    @classmethod
    def defaults(cls) -> dict:
        """The constructor's default of each setting."""
        params = inspect.signature(cls.__init__).parameters
        return {k: params[k].default for k in cls.SETTINGS if k in params and params[k].default is not params[k].empty}

    @classmethod
    def check_together(cls, settings: dict, where: str) -> None:
        """InputError if settings each in range do not go together (a minimum above its value);
        ``settings``: the constructor's defaults with the file's values over them."""

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


def check_settings(name: str, params: Any) -> None:
    """InputError naming the first setting of configs/search/NAME.yaml the optimiser ``name`` does
    not take, or whose value is out of its range (``SETTINGS``) or does not go with the others:
    checked before a run starts, so that none fails (or fills the memory) in its first scene."""
    where = f"configs/search/{name}.yaml"
    if not isinstance(params, dict):
        raise InputError(f"{where}: expected a mapping of settings, got {str(params)[:40]}")
    optimizer = SEARCHES.entry(name)
    known = optimizer.settings()
    unknown = sorted(set(params) - set(known), key=str)
    if unknown:
        raise InputError(f"{where}: unknown setting '{unknown[0]}' for {name}; "
                         f"known: {', '.join(sorted(known)) or 'none'}")
    for key, value in params.items():
        optimizer.SETTINGS[key].check(value, f"{where}: {key}")
    optimizer.check_together(optimizer.defaults() | params, where)


def build_optimizer(name: str, dim: int, budget: int, rng: np.random.Generator, **params) -> Optimizer:
    check_settings(name, params)
    return SEARCHES.entry(name)(dim, budget, rng, **params)
