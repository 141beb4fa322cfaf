"""How a hardening round trains its target one round further: one interface, :class:`RoundTrainer`,
with an implementation per training kind of the target (asg.perception.targets.Training): asg's own
trainer (``asg``) and OpenCOOD's (``opencood``), each a module of this package registered in
:data:`ROUND_TRAINERS`. The round loop, the guard and the re-attack (asg.workflows.harden) are the
same for both: they ask the trainer for the start, a round's training, what follows it (a point
stage), the guard's average, and where the start's evaluations are cached, and run every model as a
:class:`Model` (a target and a weights file)."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from sumo_scenarios.errors import InputError

from ...perception.targets import Target
from ...registry import Registry

#: the stem of a round's model averaged with its start's (the guard's cure), in the round's folder
AVERAGED = "averaged"
#: the record of a training, in the folder it trained in (a resumed run reads it, not trains again)
TRAINED = "trained.json"
#: the round trainers, by the training kind of the target they train (its ``Training`` value)
ROUND_TRAINERS: Registry[type["RoundTrainer"]] = Registry("round trainer", "--fusion")


@dataclass(frozen=True)
class Model:
    """A model a round starts from or ends with.

    ``target``: what runs it (a shipped model, or the OpenCOOD model folder the round wrote);
    ``weights``: the weights file its detector loads (None: the target's own, an OpenCOOD folder's
    checkpoint); ``path``: what a card records of it (the weights file, or the model folder)."""
    target: Target
    weights: Path | None
    path: Path

    @property
    def weights_arg(self) -> str | None:
        """``weights`` as the ``weights_file`` argument of asg.evaluation.evaluate and the generator."""
        return str(self.weights) if self.weights is not None else None


class RoundTrainer:
    """Trains ``target`` round by round with the harden settings ``cfg``
    (asg.workflows.harden.HardenConfig; a fine-tuning's, asg.training.config.FinetuneConfig) on
    ``threads`` threads, reading the loop's settings and its own part of the block (the one named
    by its kind, ``cfg.asg`` or ``cfg.opencood``), no other trainer's; ``config_path``: the
    ``--config`` file the settings came from (None: train.yaml). Subclasses answer every method but
    :meth:`log_start` and :meth:`check` (a subclass with more to refuse calls this class's first)."""

    def __init__(self, target: Target, cfg, threads: int = 2, config_path: Path | None = None):
        self.target, self.cfg, self.threads, self.config_path = target, cfg, threads, config_path

    def check(self, weights: Path | None, given: dict | None, shipped: dict) -> None:
        """Refuse (one InputError) before any work: a block ``given`` (a ``--config`` file's; None:
        train.yaml's) whose part for another trainer differs from train.yaml's ``shipped`` (it would
        be ignored); a subclass then refuses a target whose own training settings it cannot train
        with, or a start ``weights`` it cannot take."""
        mine, given = self.target.training.value, given or {}
        for kind in sorted(k for k in ROUND_TRAINERS.names() if k != mine and k in given):
            theirs, default = given[kind], shipped.get(kind)
            if isinstance(theirs, dict) and isinstance(default, dict):
                changed = sorted(k for k in theirs if theirs[k] != default.get(k))
            else:
                changed = [kind] if theirs != default else []
            if changed:
                where = f"{self.config_path}: " if self.config_path else ""
                raise InputError(f"{where}{', '.join(changed)} of the block's {kind} part set the {kind} trainer, which "
                                 f"does not train '{self.target.name}': its trainer ({mine}) reads the block's {mine} part")

    def start(self, weights: Path | None) -> Model:
        """The model round 1 starts from (``weights``, else the target's own)."""
        raise NotImplementedError

    def is_own_start(self, start: Model) -> bool:
        """Is ``start`` the target as shipped (its own attack is its challenging val set)?"""
        raise NotImplementedError

    def model_at(self, path: Path) -> Model:
        """The model a card recorded at ``path`` (a resumed run)."""
        raise NotImplementedError

    def digest(self, model: Model):
        """The sha256 of what ``model`` loads (a hex string, or one per file), for its card."""
        raise NotImplementedError

    def settings(self, start: Model) -> dict:
        """What the run folder's run.json records of the start and of this trainer's settings."""
        raise NotImplementedError

    def prepare(self) -> None:
        """Build what the run needs once its folder is claimed, before round 0."""
        raise NotImplementedError

    def train(self, start: Model, scenes: dict[str, list], folder: Path, log: Callable[[str], None],
              progress, name: str = "weights", shared: Path | None = None) -> tuple[Model, dict]:
        """Train from ``start`` on ``scenes`` ({label: scenes}: a round's, and with ``keep_previous``
        every earlier round's; a fine-tuning's challenging set) beside the train splits of
        ``mix_with``, in ``folder`` (resumable), the model called ``name`` where a kind names it;
        ``shared``: a folder of the run where what every round needs alike is made once (default
        ``folder``). The trained model and the record of its training."""
        raise NotImplementedError

    def after_training(self, model: Model, round_dir: Path, log: Callable[[str], None]) -> dict | None:
        """What a trained (or averaged) model gets before it is evaluated: its record (None: nothing)."""
        raise NotImplementedError

    def average(self, start: Model, trained: Model, share: float, round_dir: Path) -> Model:
        """``(1 - share) * start + share * trained`` written in ``round_dir`` (the guard's cure)."""
        raise NotImplementedError

    def start_cache(self, start: Model) -> Path:
        """Where the start's evaluations are cached: a folder of the data root named by the digest
        of what it loads, shared by every run and control that starts from it."""
        raise NotImplementedError

    def log_start(self, start: Model, log: Callable[[str], None]) -> None:
        """One line about the start a user should read (nothing by default)."""


def is_kept(row: dict) -> bool:
    """Whether a harden card's round keeps its model (every round before the guard existed did)."""
    return bool(row.get("weights")) and row.get("guard", {}).get("kept", True)


def round_trainer(target: Target, cfg, threads: int = 2, config_path: Path | None = None) -> RoundTrainer:
    """The round trainer of ``target``'s training kind; InputError (its one line) for a target
    nothing here trains. The trainer's :meth:`RoundTrainer.check` refuses what it cannot train."""
    if target.training.value not in ROUND_TRAINERS:  # (the package imports every trainer module)
        raise InputError(target.not_trained_here())
    return ROUND_TRAINERS.entry(target.training.value)(target, cfg, threads, config_path)
