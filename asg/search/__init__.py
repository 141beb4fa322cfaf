"""Adversarial Perturbation Search: space and feasible set, optimisers (one file each: rs, ga, bo,
ng, registered by name behind optimizer.Optimizer), the loop."""
from . import bayesian, genetic, nevergrad_search, random_search  # noqa: F401  (their registration fills SEARCHES)
from .bayesian import BayesianOptimization
from .genetic import GeneticAlgorithm
from .loop import Evaluation, best_of, run_search
from .optimizer import SEARCHES, Optimizer, build_optimizer, check_settings
from .random_search import RandomSearch
from .space import EmptyFeasibleSet, FeasibleSet, Perturbation, SearchSpace, SpaceConfig

__all__ = ["SEARCHES", "BayesianOptimization", "EmptyFeasibleSet", "Evaluation", "FeasibleSet", "GeneticAlgorithm", "Optimizer", "Perturbation",
           "RandomSearch", "SearchSpace", "SpaceConfig", "best_of", "build_optimizer", "check_settings",
           "run_search"]
