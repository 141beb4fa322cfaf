"""Fusion methods, registered by name: none, late, early, attfuse."""
from . import attfuse, early, single  # noqa: F401  (fill the registry)
from .base import Detections, V2XDetector

__all__ = ["Detections", "V2XDetector", "build_detector"]


def build_detector(name: str, **kwargs) -> V2XDetector:
    """The detector registered as ``name`` with its shipped weights (or ``weights_file``)."""
    from ...registry import lookup

    return lookup("fusion", name)(**kwargs)
