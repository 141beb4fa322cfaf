"""Perturbation spaces, registered by name (``space``): every module of this package is imported here
and registers its space in SPACES."""
from ...registry import import_modules

import_modules(__name__, __path__)
from .base import SPACES, PerturbationSpace, Slot, SpaceContext
from .dropout import DropoutConfig
from .insert import INSERT_PREFIX, InsertConfig
from .latency import LatencyConfig
from .pose_error import PoseErrorConfig

__all__ = ["SPACES", "DropoutConfig", "INSERT_PREFIX", "InsertConfig", "LatencyConfig", "PerturbationSpace", "PoseErrorConfig",
           "Slot", "SpaceContext"]
