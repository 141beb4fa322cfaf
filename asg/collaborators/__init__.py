"""Adversarial Collaborator Search (ACS): strategies registered by name (``attention``: ACS-A,
``random``: ACS-R; see base.CollaboratorSearch), and the sampling they draw with."""
from . import attention, random_search  # noqa: F401  (their registration fills ACS_STRATEGIES)
from .base import ACS_STRATEGIES, CollaboratorSearch
from .sampling import attention_combinations, combination_weakness, random_combinations

__all__ = ["ACS_STRATEGIES", "CollaboratorSearch", "attention_combinations", "combination_weakness", "random_combinations"]
