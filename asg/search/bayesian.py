"""Bayesian optimisation (bo) with scikit-optimize, the paper's best search."""
from __future__ import annotations

import numpy as np

from .optimizer import SEARCHES, Optimizer, checked_batch


@SEARCHES.register("bo")
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
    itself is still updated with every observation).

    Batches (``batch`` > 1): after the random start, ``batch`` candidates are proposed before their
    losses are told, by the constant liar (``cl_min``, as skopt's ``ask(n_points)``): each point
    proposed is told to a copy of the latest GP (its kernel held) with the lowest loss seen so far,
    and the next is that copy's lowest LCB; the real losses replace the lies when they are told. The
    random start is proposed at once whatever ``batch`` is (a tell does not change it)."""

    def __init__(self, dim: int, budget: int, rng: np.random.Generator, n_initial: int = 20, kappa: float = 2.5,
                 refit_every: int = 5, batch: int = 1):
        super().__init__(dim, budget, rng)
        self.batch = checked_batch("bo", batch)
        self._pending: list[np.ndarray] = []  # asked in this batch, not told yet
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

    def ready(self) -> int:
        if not self.opt.models:
            return max(1, self.n_initial - self.told)
        return self.batch

    def ask(self, candidates: np.ndarray) -> np.ndarray:
        if not self.opt.models:
            return self._uniform_pick(candidates)
        from skopt.acquisition import gaussian_lcb

        model = self._lying_model() if self._pending else self.opt.models[-1]
        lcb = gaussian_lcb(self._unit(candidates), model, kappa=self.kappa)
        x = candidates[int(np.argmin(lcb))]
        self._pending.append(np.asarray(x, dtype=float))
        return x

    def _unit(self, points: np.ndarray) -> np.ndarray:
        """``points`` (K, D) in the GP's units: skopt normalises each [-1, 1] dimension to [0, 1]
        (``space.transform``, the same floats, without its loop over every value in Python)."""
        return (np.asarray(points, dtype=float) - -1.0) / (1.0 - -1.0)

    def _lying_model(self):
        """The latest GP, its kernel held, refitted with the points asked in this batch told the
        lowest loss seen so far (the constant liar, cl_min)."""
        from sklearn.base import clone

        xs = np.vstack([self.opt.space.transform(self.opt.Xi), self._unit(np.clip(self._pending, -1.0, 1.0))])
        ys = list(self.opt.yi) + [min(self.opt.yi)] * len(self._pending)
        gp = clone(self.opt.models[-1]).set_params(kernel=self.opt.models[-1].kernel_, optimizer=None)
        return gp.fit(xs, ys)

    def tell(self, x: np.ndarray, loss: float) -> None:
        self._pending = [p for p in self._pending if not np.array_equal(p, x)]
        self.told += 1
        fitting = self.told - self.n_initial
        refit = fitting <= 0 or fitting % self.refit_every == 0
        self.opt.base_estimator_.set_params(optimizer="fmin_l_bfgs_b" if refit else None)
        self.opt.tell([float(v) for v in np.clip(x, -1.0, 1.0)], float(loss))
        if self.opt.models:
            self.opt.base_estimator_.set_params(kernel=self.opt.models[-1].kernel_)
