"""Adversarial Collaborator Search (ACS): attention-based sampling (ACS-A) and a random baseline (ACS-R)."""
from .sampling import attention_combinations, combination_weakness, random_combinations

__all__ = ["attention_combinations", "combination_weakness", "random_combinations"]
