"""Bayesian optimisation (bo) with scikit-optimize's Gaussian process, the paper's best search."""
from __future__ import annotations

import warnings

import numpy as np

from .optimizer import BATCH, SEARCHES, Optimizer, Setting


@SEARCHES.register("bo")
class BayesianOptimization(Optimizer):
    """scikit-optimize's GP (Matern 2.5) surrogate fitted on every point told, as skopt's
    ``Optimizer`` fits it: the first ``n_initial`` points (at most budget - 1) uniform over the
    candidates, then the candidate with the lowest lower confidence bound (kappa 2.5; LCB is UCB for
    minimisation) under the latest GP. The loss is told as is: skopt minimises it (the reference
    code's sign defect is not repeated).

    The acquisition is minimised over the candidates (Q's members not evaluated yet) rather than
    over skopt's random points in the box: Q is finite, so its best member is the point the search
    can actually evaluate (a random point's nearest member can be far from it in 9-D).

    The GP is fitted here as skopt's ``Optimizer.tell`` fits it (a clone of the base GP, the told
    points in its [0, 1] units, the losses as told; the same numbers), without the rest of what
    that tell does (its own sampling of next points, which this search does not use). Its kernel's
    hyperparameters are refitted (L-BFGS) every ``refit_every`` tells and held fixed in between
    (the GP itself is still updated with every observation).

    Batches (``batch`` > 1): after the random start, ``batch`` candidates are proposed before their
    losses are told, by the constant liar (``cl_min``, as skopt's ``ask(n_points)``): each point
    proposed is told to a copy of the latest GP (its kernel held) with the lowest loss seen so far,
    and the next is that copy's lowest LCB; the real losses replace the lies when they are told. The
    random start is proposed at once whatever ``batch`` is (a tell does not change it)."""

    SETTINGS = {"n_initial": Setting(int, 1, 10_000), "kappa": Setting(float, 0.0, 100.0),
                "refit_every": Setting(int, 1, 10_000), "batch": BATCH}

    def __init__(self, dim: int, budget: int, rng: np.random.Generator, n_initial: int = 20, kappa: float = 2.5,
                 refit_every: int = 5, batch: int = 1):
        super().__init__(dim, budget, rng)
        self.batch = batch
        self._pending: list[np.ndarray] = []  # asked in this batch, not told yet
        n_initial = min(int(n_initial), max(1, budget - 1))  # a small budget still gets a guided step
        self.n_initial = n_initial
        self.kappa = kappa
        self.refit_every = refit_every
        self.told = 0
        from skopt.learning import GaussianProcessRegressor
        from skopt.learning.gaussian_process.kernels import ConstantKernel, Matern, WhiteKernel

        seed = int(rng.integers(2**31 - 1))
        kernel = ConstantKernel(1.0, (0.01, 1000.0)) * Matern(length_scale=np.ones(dim), length_scale_bounds=(0.01, 100.0), nu=2.5) \
            + WhiteKernel(1e-4, (1e-6, 1e-1))
        #: the GP each fit clones: its kernel the latest fit's (its hyperparameters held between refits)
        self._base = GaussianProcessRegressor(kernel=kernel, normalize_y=True, noise=None, n_restarts_optimizer=0,
                                              random_state=seed)
        self._xs: list[np.ndarray] = []  # the points told (each (D,)), in the GP's units
        self._ys: list[float] = []  # their losses, as told
        self._model = None  # the latest GP fitted (None: still in the random start)

    def ready(self) -> int:
        if self._model is None:
            return max(1, self.n_initial - self.told)
        return self.batch

    def ask(self, candidates: np.ndarray) -> np.ndarray:
        if self._model is None:
            return self._uniform_pick(candidates)
        from skopt.acquisition import gaussian_lcb

        model = self._lying_model() if self._pending else self._model
        lcb = gaussian_lcb(self._unit(candidates), model, kappa=self.kappa)
        x = candidates[int(np.argmin(lcb))]
        self._pending.append(np.asarray(x, dtype=float))
        return x

    def _unit(self, points: np.ndarray) -> np.ndarray:
        """``points`` (K, D) or (D,) in the GP's units: skopt normalises each [-1, 1] dimension to
        [0, 1] (``space.transform``, the same floats, without its loop over every value in Python)."""
        return (np.asarray(points, dtype=float) - -1.0) / (1.0 - -1.0)

    def _fitted(self, xs: list[np.ndarray], ys: list[float], refit: bool):
        """A clone of the base GP fitted on ``xs`` (each (D,), GP units) and ``ys``; its kernel's
        hyperparameters refitted by L-BFGS if ``refit``, else held."""
        from sklearn.base import clone

        gp = clone(self._base).set_params(optimizer="fmin_l_bfgs_b" if refit else None)
        with warnings.catch_warnings():  # as skopt fits it: L-BFGS's convergence notes are not the user's
            warnings.simplefilter("ignore")
            return gp.fit(np.vstack(xs), ys)

    def _lying_model(self):
        """The latest GP, its kernel held, refitted with the points asked in this batch told the
        lowest loss seen so far (the constant liar, cl_min)."""
        from sklearn.base import clone

        xs = np.vstack([np.vstack(self._xs), self._unit(np.clip(self._pending, -1.0, 1.0))])
        ys = self._ys + [min(self._ys)] * len(self._pending)
        gp = clone(self._model).set_params(kernel=self._model.kernel_, optimizer=None)
        return gp.fit(xs, ys)

    def tell(self, x: np.ndarray, loss: float) -> None:
        self._pending = [p for p in self._pending if not np.array_equal(p, x)]
        self.told += 1
        self._xs.append(self._unit(np.clip(np.asarray(x, dtype=float), -1.0, 1.0)))
        self._ys.append(float(loss))
        fitting = self.told - self.n_initial
        if fitting < 0:  # the random start: no GP yet
            return
        self._model = self._fitted(self._xs, self._ys, refit=fitting % self.refit_every == 0)
        self._base.set_params(kernel=self._model.kernel_)
