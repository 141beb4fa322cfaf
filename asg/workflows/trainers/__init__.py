"""A hardening round's training, one module per training kind of the target (asg.workflows.trainers.base)."""
from ...registry import import_modules
from .base import ROUND_TRAINERS, Model, RoundTrainer, round_trainer

__all__ = ["ROUND_TRAINERS", "Model", "RoundTrainer", "round_trainer"]

import_modules(__name__, __path__)
