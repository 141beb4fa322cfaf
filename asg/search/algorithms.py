"""Black-box optimisers behind one ask/tell interface, registered by name: rs, ga, bo, ng (nevergrad).

All work in normalised units x in [-1, 1]^D and minimise the loss. ``ask`` gets the candidates, the
members of the feasible set Q not evaluated yet (K, D), and returns a point; the search loop
evaluates the candidate nearest to it, and ``tell`` receives that point.
"""
from __future__ import annotations

import inspect
import math
from abc import ABC, abstractmethod
from dataclasses import dataclass, fields

import numpy as np

from sumo_scenarios.errors import InputError

from ..registry import lookup, register


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


@register("search", "rs")
class RandomSearch(Optimizer):
    """Uniform over Q's members not evaluated yet (drawing without replacement from Q)."""

    def ask(self, candidates: np.ndarray) -> np.ndarray:
        return self._uniform_pick(candidates)

    def tell(self, x: np.ndarray, loss: float) -> None:
        pass


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


@register("search", "ga")
class GeneticAlgorithm(Optimizer):
    """Elitism, softmax parent selection on negated loss (temperature 0.8), uniform crossover,
    adaptive mutation: probability and range shrink by x0.9 when a generation does not improve.

    The first generation is ``population`` random points; each later one ``population - elites``
    children, bred from the best ``population`` of the last generation plus the elites carried over
    with their known loss (an elite is not evaluated again)."""

    @classmethod
    def settings(cls) -> tuple[str, ...]:
        return tuple(f.name for f in fields(GAParams))

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


@register("search", "bo")
class BayesianOptimization(Optimizer):
    """scikit-optimize's Optimizer: a GP (Matern 2.5) surrogate fitted on every point told; the first
    ``n_initial`` points (at most budget - 1) uniform over the candidates, then the candidate with
    the lowest lower confidence bound (kappa 2.5; LCB is UCB for minimisation) under the latest GP. The loss is told
    as is: skopt minimises it (the reference code's sign defect is not repeated).

    The acquisition is minimised over the candidates (Q's members not evaluated yet) rather than
    over skopt's random points in the box: Q is finite, so its best member is the point the search
    can actually evaluate (a random point's nearest member can be far from it in 9-D).

    Cost: skopt refits the GP's kernel hyperparameters (L-BFGS) at every tell, which dominates its
    overhead; here they are refitted every ``refit_every`` tells and held fixed in between (the GP
    itself is still updated with every observation)."""

    def __init__(self, dim: int, budget: int, rng: np.random.Generator, n_initial: int = 20, kappa: float = 2.5,
                 refit_every: int = 5):
        super().__init__(dim, budget, rng)
        n_initial = min(int(n_initial), max(1, budget - 1))  # a small budget still gets a guided step
        self.n_initial = n_initial
        self.kappa = kappa
        self.refit_every = max(1, refit_every)
        self.told = 0
        from skopt import Optimizer as SkOptimizer
        from skopt.learning import GaussianProcessRegressor
        from skopt.learning.gaussian_process.kernels import ConstantKernel, Matern, WhiteKernel

        seed = int(rng.integers(2**31 - 1))
        kernel = ConstantKernel(1.0, (0.01, 1000.0)) * Matern(length_scale=np.ones(dim), length_scale_bounds=(0.01, 100.0), nu=2.5) \
            + WhiteKernel(1e-4, (1e-6, 1e-1))
        gp = GaussianProcessRegressor(kernel=kernel, normalize_y=True, noise=None, n_restarts_optimizer=0, random_state=seed)
        # skopt's own next-point sampling after each fit is not used (ask picks among the
        # candidates): one sample keeps it cheap
        self.opt = SkOptimizer([(-1.0, 1.0)] * dim, base_estimator=gp, n_initial_points=n_initial,
                               initial_point_generator="random", acq_func="LCB", acq_optimizer="sampling",
                               acq_func_kwargs={"kappa": kappa}, acq_optimizer_kwargs={"n_points": 1},
                               random_state=seed)

    def ask(self, candidates: np.ndarray) -> np.ndarray:
        if not self.opt.models:
            return self._uniform_pick(candidates)
        from skopt.acquisition import gaussian_lcb

        lcb = gaussian_lcb(self.opt.space.transform(candidates.tolist()), self.opt.models[-1], kappa=self.kappa)
        return candidates[int(np.argmin(lcb))]

    def tell(self, x: np.ndarray, loss: float) -> None:
        self.told += 1
        fitting = self.told - self.n_initial
        refit = fitting <= 0 or fitting % self.refit_every == 0
        self.opt.base_estimator_.set_params(optimizer="fmin_l_bfgs_b" if refit else None)
        self.opt.tell([float(v) for v in np.clip(x, -1.0, 1.0)], float(loss))
        if self.opt.models:
            self.opt.base_estimator_.set_params(kernel=self.opt.models[-1].kernel_)


@register("search", "ng")
class NevergradSearch(Optimizer):
    """A nevergrad optimiser (default NGOpt, its own pick of algorithm for the dimension and budget;
    nevergrad also handles discrete and mixed dimensions) over the box [-1, 1]^D, seeded from the
    scene's generator. ``tell`` gives it the loss of the member of Q nearest to what it asked (the
    projection is part of the objective it sees); the unperturbed start, which it did not ask for,
    is not told to it."""

    def __init__(self, dim: int, budget: int, rng: np.random.Generator, optimizer: str = "NGOpt"):
        super().__init__(dim, budget, rng)
        import warnings

        import nevergrad as ng

        warnings.filterwarnings("ignore", module="nevergrad")  # advice on bound widths, not errors
        if optimizer not in ng.optimizers.registry:
            raise InputError(f"search ng: unknown nevergrad optimizer {optimizer!r} (configs/search/ng.yaml)")
        param = ng.p.Array(shape=(dim,), lower=-1.0, upper=1.0)
        param.random_state = np.random.RandomState(int(rng.integers(2**31 - 1)))
        self._opt = ng.optimizers.registry[optimizer](parametrization=param, budget=budget, num_workers=1)
        self._asked = None

    def ask(self, candidates: np.ndarray) -> np.ndarray:
        self._asked = self._opt.ask()
        return np.asarray(self._asked.value, dtype=float)

    def tell(self, x: np.ndarray, loss: float) -> None:
        if self._asked is not None:
            self._opt.tell(self._asked, float(loss))
            self._asked = None


def check_settings(name: str, params: dict) -> None:
    """InputError naming the first setting the optimiser ``name`` does not take."""
    known = lookup("search", name).settings()
    unknown = sorted(set(params) - set(known))
    if unknown:
        raise InputError(f"configs/search/{name}.yaml: unknown setting '{unknown[0]}' for {name}; "
                         f"known: {', '.join(sorted(known)) or 'none'}")


def build_optimizer(name: str, dim: int, budget: int, rng: np.random.Generator, **params) -> Optimizer:
    check_settings(name, params)
    return lookup("search", name)(dim, budget, rng, **params)
