"""Perturbation spaces, registered by name (``space``): poses, insert, pose-error, latency, dropout."""
from . import dropout, insert, latency, pose_error, poses  # noqa: F401  (their registration fills SPACES)
from .base import SPACES, PerturbationSpace, Slot, SpaceContext
from .dropout import DropoutConfig
from .insert import INSERT_PREFIX, InsertConfig
from .latency import LatencyConfig
from .pose_error import PoseErrorConfig

__all__ = ["SPACES", "DropoutConfig", "INSERT_PREFIX", "InsertConfig", "LatencyConfig", "PerturbationSpace", "PoseErrorConfig",
           "Slot", "SpaceContext"]
