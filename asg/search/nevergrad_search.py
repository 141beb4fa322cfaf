"""Any nevergrad optimiser (ng; default NGOpt)."""
from __future__ import annotations

import numpy as np

from sumo_scenarios.errors import InputError

from .optimizer import BATCH, SEARCHES, Optimizer, Setting


@SEARCHES.register("ng")
class NevergradSearch(Optimizer):
    """A nevergrad optimiser (default NGOpt, its own pick of algorithm for the dimension and budget;
    nevergrad also handles discrete and mixed dimensions) over the box [-1, 1]^D, seeded from the
    scene's generator. ``tell`` gives it the loss of the member of Q nearest to what it asked (the
    projection is part of the objective it sees); the unperturbed start, which it did not ask for,
    is not told to it. ``batch``: how many points it proposes before their losses are told (its
    ``num_workers``; 1 asks one at a time)."""

    SETTINGS = {"optimizer": Setting(str), "batch": BATCH}

    @classmethod
    def check_together(cls, settings: dict, where: str) -> None:
        import nevergrad as ng

        if settings["optimizer"] not in ng.optimizers.registry:
            raise InputError(f"{where}: unknown nevergrad optimizer {settings['optimizer']!r}; one of nevergrad's "
                             "registry, e.g. NGOpt, CMA, TwoPointsDE")

    def __init__(self, dim: int, budget: int, rng: np.random.Generator, optimizer: str = "NGOpt", batch: int = 1):
        super().__init__(dim, budget, rng)
        self.batch = batch
        import warnings

        import nevergrad as ng

        warnings.filterwarnings("ignore", module="nevergrad")  # advice on bound widths, not errors
        param = ng.p.Array(shape=(dim,), lower=-1.0, upper=1.0)
        param.random_state = np.random.RandomState(int(rng.integers(2**31 - 1)))
        self._opt = ng.optimizers.registry[optimizer](parametrization=param, budget=budget, num_workers=batch)
        self._asked: list = []  # asked and not told yet, in the order asked (the loop tells in that order)

    def ready(self) -> int:
        return self.batch

    def ask(self, candidates: np.ndarray) -> np.ndarray:
        self._asked.append(self._opt.ask())
        return np.asarray(self._asked[-1].value, dtype=float)

    def tell(self, x: np.ndarray, loss: float) -> None:
        if self._asked:
            self._opt.tell(self._asked.pop(0), float(loss))
