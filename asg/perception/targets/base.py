"""What is attacked: a target, resolved from ``--fusion`` into an object that answers what
callers ask (its label and digests, its detector, its attention, how it is trained, what it cannot
do), so that nothing below the command line tells the kinds apart by their names.

A target kind is one class of this package registered in :data:`TARGET_KINDS`. A name goes to the
first kind, in ``order``, that claims it: a prefixed name (``opencood:DIR``) to its prefix's kind,
then a shipped model's name, then an installed plugin's (so a shipped model wins over a plugin of
the same name)."""
from __future__ import annotations

import enum
from typing import ClassVar

from sumo_scenarios.errors import InputError

from ...registry import Registry


class Training(enum.Enum):
    """Who trains a target's weights (``asg train``, ``finetune``, ``harden``)."""
    ASG = "asg"            # asg's own trainer: a shipped model's network and feed
    OPENCOOD = "opencood"  # OpenCOOD's own trainer, run on the model folder's config
    NONE = "none"          # it brings its own weights: nothing here trains it


#: the target kinds (one module of this package each)
TARGET_KINDS: Registry[type["Target"]] = Registry("target kind", "--fusion", ordered=True)


class Target:
    """One target (the detector attacked). Subclasses set the class attributes and answer the
    methods that differ; ``name`` is the text the user gave (what run folders record)."""
    #: the rank in which kinds claim a name (lowest first)
    order: ClassVar[int] = 100
    #: is it named by a prefix (asg.registry.TARGET_PREFIXES) and a path?
    prefixed: ClassVar[bool] = False
    #: who trains it
    training: ClassVar[Training] = Training.NONE
    #: how a table's header names the detectors of this kind
    header: ClassVar[str] = "detectors"
    #: does ``asg bench detect`` time the framework's own pipeline beside asg's run of it?
    has_reference_pipeline: ClassVar[bool] = False
    #: can its detector score a frame by its framework's own test-time ground truth
    #: (``opencood_frame``: ``asg evaluate --ground-truth opencood``)?
    own_ground_truth: ClassVar[bool] = False
    #: may its detector detect frames on several threads at once, each frame's detections the same
    #: bits on any thread (a search's candidates are then scored side by side: asg.generator.candidates)?
    concurrent_frames: ClassVar[bool] = False

    def __init__(self, name: str):
        self.name = name

    @property
    def kind(self) -> str:
        """The kind's name in TARGET_KINDS ("shipped", "plugin", "opencood")."""
        return type(self).registry_name

    def __eq__(self, other) -> bool:
        return type(other) is type(self) and other.name == self.name

    def __hash__(self) -> int:
        return hash((type(self), self.name))

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.name!r})"

    @classmethod
    def claims(cls, name: str) -> bool:
        """Is ``name`` a target of this kind (by its form alone: nothing is loaded)?"""
        raise NotImplementedError

    @property
    def label(self) -> str:
        """A file-name-safe name of the target for what is made against it (a set, a table row)."""
        return self.name

    def detector(self, weights_file: str | None = None, **options):
        """The detector, ready to detect; InputError if it cannot be built. ``options``: settings
        only a shipped model takes (its ``cfg``)."""
        raise NotImplementedError

    def _no_options(self, options: dict) -> None:
        if options:
            raise InputError(f"'{self.name}' takes no detector settings ({', '.join(sorted(options))}); "
                             "they apply to the shipped models")

    def check(self, weights_file: str | None = None) -> "Target":
        """Refuse (one InputError) a target, or its ``weights_file``, that cannot run, before any
        work starts; the detector built here is the one a later :meth:`detector` call returns
        where its kind keeps it (nothing is loaded twice)."""
        self.detector(weights_file)
        return self

    @property
    def own_attention(self) -> bool:
        """Does it bring the attention ACS-A reads?"""
        return False

    @property
    def borrows_attention(self) -> bool:
        """Does ACS-A read the shipped AttFuse's attention in its stead?"""
        return not self.own_attention

    @property
    def shipped_weights(self) -> str | None:
        """The shipped weights file's name its detector loads when given none (None: not shipped)."""
        return None

    def run_record(self) -> dict:
        """What a run folder's run.json records of it beyond its name (digests of its files), so
        that a rerun after they changed is refused."""
        return {}

    def evaluation_note(self) -> str:
        """One line a user scoring it should read ('' for none)."""
        return ""

    def shipped_entry(self):
        """The registry entry of a shipped model (its class: weights, network, feed); InputError
        for any other kind (nothing of asg trains it)."""
        raise InputError(self.not_trained_here())

    def not_trained_here(self) -> str:
        """The one line refusing to train it with asg's trainer."""
        return f"'{self.name}' brings its own weights; asg trains the shipped models only ({shipped_list()})"

    @classmethod
    def help_names(cls) -> list[str]:
        """The names of this kind that ``--help`` lists (a prefixed kind: its form, ``PREFIX:DIR``)."""
        return []


def shipped_list() -> str:
    """The shipped models' names, for a message."""
    from ..fusion import FUSIONS

    return ", ".join(FUSIONS.names())


def resolve_target(name: str) -> Target:
    """The target ``name`` names; InputError (one line with the known names) if no kind claims it.
    A few microseconds, and asked of today's registries each time (a plugin installed or a model
    registered since is seen); what is costly to build, an OpenCOOD model, its kind keeps."""
    if not isinstance(name, str):
        raise InputError(f"--fusion takes a name, got {type(name).__name__}")
    kind = next((k for k in sorted(TARGET_KINDS.entries(), key=lambda k: k.order) if k.claims(name)), None)
    if kind is None:
        from ...registry import safe_name

        raise InputError(f"unknown fusion {safe_name(name)}; known: {', '.join(detector_names())}")
    return kind(name)


def detector_names() -> list[str]:
    """Every detector ``--fusion`` accepts: the shipped models' and installed plugins' names (sorted),
    then each prefixed kind's form (``opencood:DIR``)."""
    kinds = TARGET_KINDS.entries()
    return (sorted({n for k in kinds if not k.prefixed for n in k.help_names()})
            + [n for k in kinds if k.prefixed for n in k.help_names()])
