"""Fusion methods, registered by name in ``FUSIONS`` (one module of this package each, imported
here; ``asg --help`` and ``FUSIONS.names()`` list them). A ``--fusion`` name becomes a target (a
shipped model, a plugin, an OpenCOOD folder) in asg.perception.targets."""
from sumo_scenarios.errors import InputError

from ...registry import import_modules

from .base import FUSIONS, Detections, V2XDetector

import_modules(__name__, __path__)  # each module registers its detectors: a new model adds no import line

__all__ = ["FUSIONS", "Detections", "V2XDetector", "build_network", "card_settings_of", "detector_config_of", "feed_of",
           "fusions_of", "has_own_attention", "weights_names"]


#: the shipped model whose attention ACS-A reads for a target without attention of its own
ATTENTION_LENDER = "attfuse"


def has_own_attention(model) -> bool:
    """Does a detector (an instance or its registry entry) bring the attention ACS-A reads (its
    ``has_attention``)? Without it, ACS-A borrows the shipped AttFuse's."""
    return bool(getattr(model, "has_attention", False))


def _entries() -> list[type[V2XDetector]]:
    return FUSIONS.entries()


def weights_names() -> list[str]:
    """The shipped weights files' names (none and late share 'single')."""
    return sorted({cls.weights for cls in _entries()})


def fusions_of(weights_name: str) -> list[str]:
    """The shipped fusion names that run the weights ``weights_name``."""
    return [cls.registry_name for cls in _entries() if cls.weights == weights_name]


def _entry_of(weights_name: str) -> type[V2XDetector]:
    for cls in _entries():
        if cls.weights == weights_name:
            return cls
    raise InputError(f"unknown weights '{weights_name}'; choose one of {', '.join(weights_names())}")


def feed_of(weights_name: str):
    """How the network behind a weights file is trained (an asg.perception.feeds.Feed)."""
    return _entry_of(weights_name).feed


#: the settings that size a network (its weights load only into a network built with the same)
NETWORK_SIZE_KEYS = ("pillar_m", "pfn_channels", "layers", "filters", "upsample_channels")


def card_settings_of(weights_name: str, cfg) -> dict:
    """What the card of a weights file records of its network's settings ``cfg``: the settings
    file, the network's size as ``cfg`` gives it (which a caller may have set apart from the file)
    and the settings particular to its model."""
    entry = _entry_of(weights_name)
    return {"detector_config": f"configs/detectors/{entry.config_file}",
            "network": {key: getattr(cfg, key) for key in NETWORK_SIZE_KEYS}, **entry.card_settings(cfg)}


def detector_config_of(weights_name: str):
    """The settings the network of a weights file is built with (its detector's config file)."""
    return _entry_of(weights_name).detector_config()


def build_network(weights_name: str, cfg):
    """A fresh (untrained) network of the weights ``weights_name``, as its detector builds it."""
    return _entry_of(weights_name).new_network(cfg)
