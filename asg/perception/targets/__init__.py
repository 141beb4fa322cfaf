"""Targets: what ``--fusion`` names, resolved (:func:`resolve_target`) into an object of one of
the kinds registered in ``TARGET_KINDS`` (one module of this package each: a shipped model, a
detector plugin, an OpenCOOD model folder). Callers ask the object; the functions here are the
questions every command asks, put to it."""
from pathlib import Path

from ...registry import import_modules
from ..fusion import ATTENTION_LENDER, FUSIONS
from .base import TARGET_KINDS, Target, Training, detector_names, resolve_target

import_modules(__name__, __path__)  # each module registers its kind: a new kind adds no import line

__all__ = ["TARGET_KINDS", "Target", "Training", "build_detector", "check_fusion", "check_weights_file",
           "detector_names", "resolve_target", "shipped_model", "shipped_weights_of"]


def check_fusion(name: str) -> str:
    """``name`` if ``--fusion`` accepts it and it can run, else the one line every command refuses
    it with (its target's :meth:`Target.check`)."""
    return resolve_target(name).check().name


def build_detector(name: str, weights_file: str | None = None, **options):
    """The detector of the target ``name`` (a shipped model with its weights or ``weights_file``, a
    plugin, an OpenCOOD model); InputError if there is none. ``options``: a shipped model's own
    (``cfg``: other detector settings)."""
    return resolve_target(name).detector(weights_file, **options)


def check_weights_file(fusion: str, path) -> None:
    """Refuse (one InputError) a ``--weights`` file that is missing, corrupt or made for another
    model than ``fusion``'s, or given to a target that loads its own, before any work starts."""
    resolve_target(fusion).check(weights_file=str(path))


def shipped_model(fusion: str):
    """The registry entry of a shipped model: its detector class, which knows its weights file
    (``weights``), how its network is built (``new_network``) and trained (``feed``); InputError for
    any other target (nothing of asg trains it) or an unknown name."""
    return resolve_target(fusion).shipped_entry()


def shipped_weights_of(target: Target, own: bool = True, acs_attention: bool = False) -> dict[str, Path]:
    """{weights name: file} of the shipped weights a generator run against ``target`` loads: the
    target's own (a shipped model's, when ``own``: it is given no weights file) and, with
    attention-based ACS and a target without attention of its own, the shipped AttFuse's. Files not
    on disk (a plugin's) are left out."""
    from ..weights_io import weights_path

    wanted = [target.shipped_weights] if target.shipped_weights and own else []
    if acs_attention and not target.own_attention:
        wanted.append(FUSIONS.entry(ATTENTION_LENDER).weights)
    return {name: weights_path(name) for name in wanted if weights_path(name).is_file()}
