"""A genetic algorithm (ga) over Q's members."""
from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

from sumo_scenarios.errors import InputError

from .optimizer import SEARCHES, Optimizer, Setting


@dataclass
class GAParams:
    population: int = 15
    elites: int = 2
    temperature: float = 0.8
    crossover: float = 0.5
    mutation_p: float = 0.5
    mutation_p_min: float = 0.1
    mutation_range: float = 1.0
    mutation_range_min: float = 0.3
    decay: float = 0.9


@SEARCHES.register("ga")
class GeneticAlgorithm(Optimizer):
    """Elitism, softmax parent selection on negated loss (temperature 0.8), uniform crossover,
    adaptive mutation: probability and range shrink by x0.9 when a generation does not improve.

    The first generation is ``population`` random points; each later one ``population - elites``
    children, bred from the best ``population`` of the last generation plus the elites carried over
    with their known loss (an elite is not evaluated again)."""

    SETTINGS = {"population": Setting(int, 1, 1000), "elites": Setting(int, 0, 999),
                "temperature": Setting(float, 0.0, 100.0, lo_open=True), "crossover": Setting(float, 0.0, 1.0),
                "mutation_p": Setting(float, 0.0, 1.0), "mutation_p_min": Setting(float, 0.0, 1.0),
                "mutation_range": Setting(float, 0.0, 2.0, lo_open=True),
                "mutation_range_min": Setting(float, 0.0, 2.0, lo_open=True), "decay": Setting(float, 0.0, 1.0, lo_open=True)}

    @classmethod
    def defaults(cls) -> dict:
        return {f.name: f.default for f in fields(GAParams)}

    @classmethod
    def check_together(cls, settings: dict, where: str) -> None:
        if settings["elites"] >= settings["population"]:
            raise InputError(f"{where}: elites ({settings['elites']}) must be fewer than the population "
                             f"({settings['population']})")
        for low in ("mutation_p_min", "mutation_range_min"):
            if settings[low] > settings[low.removesuffix("_min")]:
                raise InputError(f"{where}: {low} ({settings[low]:g}) is above {low.removesuffix('_min')} "
                                 f"({settings[low.removesuffix('_min')]:g})")

    def __init__(self, dim: int, budget: int, rng: np.random.Generator, **params):
        super().__init__(dim, budget, rng)
        self.p = GAParams(**params)
        self.queue: list[np.ndarray] = [rng.uniform(-1, 1, dim) for _ in range(self.p.population)]
        self.generation: list[tuple[np.ndarray, float]] = []
        self.elites: list[tuple[np.ndarray, float]] = []
        self.best = math.inf
        self.mut_p = self.p.mutation_p
        self.mut_r = self.p.mutation_range

    def ask(self, candidates: np.ndarray) -> np.ndarray:
        if not self.queue:
            self._breed()
        return self.queue.pop(0)

    def tell(self, x: np.ndarray, loss: float) -> None:
        self.generation.append((np.asarray(x, dtype=float), float(loss)))

    def ready(self) -> int:
        """The rest of the current generation (the next one bred once this one is told)."""
        if not self.queue:
            self._breed()
        return len(self.queue)

    def _breed(self) -> None:
        pop = sorted(self.elites + self.generation, key=lambda t: t[1])[: self.p.population] or [(np.zeros(self.dim), 0.0)]
        gen_best = pop[0][1]
        if gen_best < self.best - 1e-9:
            self.best = gen_best
        else:
            self.mut_p = max(self.p.mutation_p_min, self.mut_p * self.p.decay)
            self.mut_r = max(self.p.mutation_range_min, self.mut_r * self.p.decay)
        fitness = -np.array([l for _, l in pop]) / self.p.temperature
        prob = np.exp(fitness - fitness.max())
        prob /= prob.sum()
        self.elites = pop[: self.p.elites]
        children: list[np.ndarray] = []
        while len(children) < max(1, self.p.population - len(self.elites)):
            a, b = self.rng.choice(len(pop), size=2, p=prob)
            mask = self.rng.random(self.dim) < self.p.crossover
            child = np.where(mask, pop[a][0], pop[b][0])
            mutate = self.rng.random(self.dim) < self.mut_p
            child = child + mutate * self.rng.uniform(-self.mut_r, self.mut_r, self.dim)
            children.append(np.clip(child, -1.0, 1.0))
        self.queue = children
        self.generation = []
