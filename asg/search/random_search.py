"""Random search (rs): the paper's baseline."""
from __future__ import annotations

import numpy as np

from .optimizer import SEARCHES, Optimizer


@SEARCHES.register("rs")
class RandomSearch(Optimizer):
    """Uniform over Q's members not evaluated yet (drawing without replacement from Q)."""

    def ask(self, candidates: np.ndarray) -> np.ndarray:
        return self._uniform_pick(candidates)

    def tell(self, x: np.ndarray, loss: float) -> None:
        pass

    def ready(self) -> int:
        return self.budget  # a tell changes nothing it proposes
