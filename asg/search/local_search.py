"""Local search (ls): a (1+1) evolution strategy over the feasible set Q."""
from __future__ import annotations

import numpy as np

from sumo_scenarios.errors import InputError

from .optimizer import SEARCHES, Optimizer, Setting


@SEARCHES.register("ls")
class LocalSearch(Optimizer):
    """A (1+1) evolution strategy in [-1, 1]^D: each ask is the incumbent (the lowest loss told so
    far) plus a Gaussian step of width ``step`` (clipped to the box; the search loop evaluates the
    member of Q nearest to it). The width follows the one-fifth success rule: times ``grow`` after a
    step that beat the incumbent, times ``grow ** -0.25`` after one that did not, kept within
    [``step_min``, ``step_max``]. Before anything is told, a uniform pick among the candidates."""

    SETTINGS = {"step": Setting(float, 0.0, 2.0, lo_open=True), "grow": Setting(float, 1.0, 10.0, lo_open=True),
                "step_min": Setting(float, 0.0, 2.0, lo_open=True), "step_max": Setting(float, 0.0, 2.0, lo_open=True)}

    @classmethod
    def check_together(cls, settings: dict, where: str) -> None:
        if not settings["step_min"] <= settings["step"] <= settings["step_max"]:
            raise InputError(f"{where}: step ({settings['step']:g}) must lie within [step_min, step_max] "
                             f"([{settings['step_min']:g}, {settings['step_max']:g}])")

    def __init__(self, dim: int, budget: int, rng: np.random.Generator, step: float = 0.5, grow: float = 1.5,
                 step_min: float = 0.02, step_max: float = 2.0):
        super().__init__(dim, budget, rng)
        self.step, self.grow, self.step_min, self.step_max = step, grow, step_min, step_max
        self._best: tuple[np.ndarray, float] | None = None

    def ask(self, candidates: np.ndarray) -> np.ndarray:
        if self._best is None:
            return self._uniform_pick(candidates)
        return np.clip(self._best[0] + self.step * self.rng.standard_normal(self.dim), -1.0, 1.0)

    def tell(self, x: np.ndarray, loss: float) -> None:
        if self._best is None:
            self._best = (np.asarray(x, dtype=float), loss)
            return
        better = loss < self._best[1]
        if better:
            self._best = (np.asarray(x, dtype=float), loss)
        factor = self.grow if better else self.grow ** -0.25
        self.step = float(np.clip(self.step * factor, self.step_min, self.step_max))
