"""Adversarial Perturbation Search: space and feasible set, optimisers (one file each, registered by
name behind optimizer.Optimizer: every module of this package is imported here), the loop."""
from ..registry import import_modules

import_modules(__name__, __path__)  # each optimiser's module registers it in SEARCHES
from .bayesian import BayesianOptimization
from .genetic import GeneticAlgorithm
from .loop import Evaluation, best_of, run_search
from .optimizer import SEARCHES, Optimizer, build_optimizer, check_settings
from .random_search import RandomSearch
from .space import EmptyFeasibleSet, FeasibleSet, Perturbation, SearchSpace, SpaceConfig

__all__ = ["SEARCHES", "BayesianOptimization", "EmptyFeasibleSet", "Evaluation", "FeasibleSet", "GeneticAlgorithm", "Optimizer", "Perturbation",
           "RandomSearch", "SearchSpace", "SpaceConfig", "best_of", "build_optimizer", "check_settings",
           "run_search"]
