"""Adversarial Perturbation Search: space and feasible set, optimisers (rs, ga, bo), the loop."""
from .algorithms import BayesianOptimization, GeneticAlgorithm, Optimizer, RandomSearch, build_optimizer, check_settings
from .loop import Evaluation, best_of, run_search
from .space import EmptyFeasibleSet, FeasibleSet, Perturbation, SearchSpace, SpaceConfig

__all__ = ["BayesianOptimization", "EmptyFeasibleSet", "Evaluation", "FeasibleSet", "GeneticAlgorithm", "Optimizer", "Perturbation",
           "RandomSearch", "SearchSpace", "SpaceConfig", "best_of", "build_optimizer", "check_settings",
           "run_search"]
