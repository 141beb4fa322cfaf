"""Fusion methods, registered by name: none, late, early, attfuse, attfuse-ft; and any detector
plugin of the ``asg.detectors`` entry point group (see asg.perception.plugins)."""
from sumo_scenarios.errors import InputError

from . import attfuse, early, single  # noqa: F401  (fill the registry)
from .base import Detections, V2XDetector

__all__ = ["Detections", "V2XDetector", "build_detector", "check_weights_file", "detector_names"]


def detector_names() -> list[str]:
    """Every detector ``--fusion`` accepts: the shipped models and the installed plugins."""
    from ...registry import names
    from ..plugins import plugin_names

    return sorted(set(names("fusion")) | set(plugin_names()))


def build_detector(name: str, **kwargs):
    """The detector called ``name``: a shipped model with its weights (or ``weights_file``), or
    an installed plugin (see asg.perception.plugins); InputError if there is none."""
    from ...registry import names, lookup
    from ..plugins import load_plugin

    if name in names("fusion"):
        return lookup("fusion", name)(**kwargs)
    plugin = load_plugin(name)
    if plugin is None:
        raise InputError(f"unknown fusion '{name}'; known: {', '.join(detector_names())}")
    if kwargs.get("weights_file"):
        raise InputError(f"--weights applies to the shipped models; the plugin '{name}' loads its own")
    return plugin


def check_weights_file(fusion: str, path) -> None:
    """Refuse (one InputError) a ``--weights`` file that is missing, corrupt or made for another
    model than ``fusion``'s, before any work starts."""
    build_detector(fusion, weights_file=str(path))
