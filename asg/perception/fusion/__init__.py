"""Fusion methods, registered by name in ``FUSIONS`` (one module of this package each, imported
here; ``asg --help`` and ``FUSIONS.names()`` list them); and any detector plugin of the
``asg.detectors`` entry point group (see asg.perception.plugins)."""
from pathlib import Path

from sumo_scenarios.errors import InputError

from ...registry import import_modules, safe_name
from ..opencood import PREFIX as OPENCOOD_PREFIX, build_opencood_detector, check_opencood, is_opencood

from .base import FUSIONS, Detections, V2XDetector

import_modules(__name__, __path__)  # each module registers its detectors: a new model adds no import line

__all__ = ["FUSIONS", "Detections", "V2XDetector", "build_detector", "build_network", "check_weights_file", "detector_names",
           "card_settings_of", "detector_config_of", "feed_of", "fusions_of", "has_own_attention", "shipped_model", "shipped_weights_of", "weights_names"]


#: the shipped model whose attention ACS-A reads for a target without attention of its own
ATTENTION_LENDER = "attfuse"


def detector_names() -> list[str]:
    """Every detector ``--fusion`` accepts: the shipped models and the installed plugins."""
    from ..plugins import plugin_names

    return sorted(set(FUSIONS.names()) | set(plugin_names())) + [f"{OPENCOOD_PREFIX}DIR"]


def check_fusion(name: str) -> str:
    """``name`` if ``--fusion`` accepts it (a shipped model or an installed plugin), else the one
    line every command refuses an unknown fusion with."""
    if is_opencood(name):
        return check_opencood(name)
    known = detector_names()
    if name not in known:
        raise InputError(f"unknown fusion {safe_name(name)}; known: {', '.join(known)}")
    return name


def build_detector(name: str, **kwargs):
    """The detector called ``name``: a shipped model with its weights (or ``weights_file``), or
    an installed plugin (see asg.perception.plugins); InputError if there is none."""
    from ..plugins import load_plugin

    if name in FUSIONS:
        return FUSIONS.entry(name)(**kwargs)
    if is_opencood(name):
        if kwargs.get("weights_file"):
            raise InputError(f"--weights applies to the shipped models; '{name}' loads its folder's checkpoint")
        return build_opencood_detector(name)
    plugin = load_plugin(name)
    if plugin is None:
        check_fusion(name)
    if kwargs.get("weights_file"):
        raise InputError(f"--weights applies to the shipped models; the plugin '{name}' loads its own")
    return plugin


def shipped_model(fusion: str) -> type[V2XDetector]:
    """The registry's entry of a shipped model: its detector class, which knows its weights file
    (``weights``), how its network is built (``new_network``) and trained (``feed``). InputError for a plugin
    (it brings its own weights: nothing of asg trains it) or an unknown name."""
    from ..plugins import plugin_names

    if fusion in FUSIONS:
        return FUSIONS.entry(fusion)
    shipped = ", ".join(FUSIONS.names())
    if is_opencood(fusion):
        raise InputError(f"'{fusion}' is an OpenCOOD model: OpenCOOD's own trainer trains it (docs/opencood.md); "
                         f"asg trains, fine-tunes and hardens the shipped models ({shipped})")
    if fusion in plugin_names():
        raise InputError(f"'{fusion}' is a detector plugin: it brings its own weights, and asg trains, fine-tunes and "
                         f"hardens the shipped models only ({shipped})")
    raise InputError(f"unknown fusion {safe_name(fusion)}; choose one of {shipped}")


def has_own_attention(model) -> bool:
    """Does a detector (an instance or its registry entry) bring the attention ACS-A reads (its
    ``has_attention``)? Without it, ACS-A borrows the shipped AttFuse's."""
    return bool(getattr(model, "has_attention", False))


def target_lacks_attention(fusion: str) -> bool:
    """Is ``fusion`` a shipped model or an OpenCOOD model without the attention ACS-A reads (so
    that ACS-A borrows the shipped AttFuse's)? False for a plugin (its own wrapper says)."""
    if fusion in FUSIONS:
        return not has_own_attention(FUSIONS.entry(fusion))
    if is_opencood(fusion):
        return not has_own_attention(build_opencood_detector(fusion))
    return False


def shipped_weights_of(fusion: str, target: bool = True, acs_attention: bool = False) -> dict[str, Path]:
    """{weights name: file} of the shipped weights a generator run of ``fusion`` loads: the target's
    own (a shipped model's, when ``target``: it is given no weights file) and, with attention-based
    ACS and a target without attention of its own, the shipped AttFuse's. Files not on disk (a
    plugin's) are left out."""
    from ..weights_io import weights_path

    cls = FUSIONS.entry(fusion) if fusion in FUSIONS else None
    wanted = [cls.weights] if cls is not None and target else []
    own = build_opencood_detector(fusion) if is_opencood(fusion) else cls
    if acs_attention and not (own is not None and has_own_attention(own)):
        wanted.append(FUSIONS.entry(ATTENTION_LENDER).weights)
    return {name: weights_path(name) for name in wanted if weights_path(name).is_file()}


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


def check_weights_file(fusion: str, path) -> None:
    """Refuse (one InputError) a ``--weights`` file that is missing, corrupt or made for another
    model than ``fusion``'s, before any work starts."""
    build_detector(fusion, weights_file=str(path))
