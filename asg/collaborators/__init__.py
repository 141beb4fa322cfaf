"""Adversarial Collaborator Search (ACS): strategies registered by name (``attention``: ACS-A,
``random``: ACS-R; see base.CollaboratorSearch), one module each (every module of this package is
imported here: a new strategy is its module), and the sampling they draw with."""
from ..registry import import_modules

import_modules(__name__, __path__)  # each strategy's module registers it in ACS_STRATEGIES
from .base import ACS_STRATEGIES, CollaboratorSearch
from .sampling import attention_combinations, combination_weakness, random_combinations

__all__ = ["ACS_STRATEGIES", "CollaboratorSearch", "attention_combinations", "combination_weakness", "random_combinations"]
