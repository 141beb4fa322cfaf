"""asg's own trainer as a hardening round's (asg.workflows.trainers.base): a shipped model's weights
fine-tuned one chunk a round (asg.workflows.trainers.chunk.fit_chunk, the ``asg`` part of the harden
block: steps, rate and mixing), a point stage fitted to them (its ``fit_stage``: train.yaml's
``point_stage`` block), the guard's average of two weights files."""
from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path
from typing import Callable

from sumo_scenarios.atomic import write_text_atomic
from sumo_scenarios.errors import InputError

from ...io.json_file import read_json
from ...perception.targets import Training
from .chunk import fit_chunk, mixed_sources
from ..harden_stage import build_stage_set, stage_config, stage_of_round
from .base import AVERAGED, ROUND_TRAINERS, TRAINED, Model, RoundTrainer, is_kept



@ROUND_TRAINERS.register(Training.ASG.value)
class ShippedRoundTrainer(RoundTrainer):
    """A shipped model, trained by asg's trainer with the block's ``asg`` part (a fine-tuning's fits
    no point stage: it has no ``fit_stage``)."""

    def __init__(self, target, cfg, threads: int = 2, config_path: Path | None = None):
        super().__init__(target, cfg, threads, config_path)
        self.weights_name = target.shipped_weights
        self.chunk = cfg.asg
        # checked (and its data set known) before any work
        self.stage_cfg = stage_config(getattr(self.chunk, "fit_stage", False))

    def start(self, weights: Path | None) -> Model:
        """``weights`` (a .pt, or a harden card: its last kept round's) or the shipped weights;
        InputError if missing or not loadable by the target's detector."""
        from ...perception.weights_io import weights_path

        if weights is None:
            return self.model_at(weights_path(self.weights_name))
        path = Path(weights)
        if path.suffix == ".json" and path.is_file():
            path = _card_weights(path, weights)
        if not path.is_file():
            raise InputError(f"--weights {path}: no such file; give a .pt written by asg train, finetune or harden")
        self.target.check(str(path))  # one clear line for a corrupt or foreign file
        return self.model_at(path)

    def is_own_start(self, start: Model) -> bool:
        return self.digest(start) == self.digest(self.start(None))

    def model_at(self, path: Path) -> Model:
        return Model(self.target, Path(path), Path(path))

    def digest(self, model: Model) -> str:
        from ...generator.run import file_digest

        return file_digest(model.path)

    def settings(self, start: Model) -> dict:
        return {"start_weights": str(start.path), "start_sha256": self.digest(start),
                "point_stage": asdict(self.stage_cfg) if self.stage_cfg else None}

    def prepare(self) -> None:
        build_stage_set(self.stage_cfg)

    def train(self, start: Model, scenes: dict[str, list], folder: Path, log: Callable[[str], None],
              progress, name: str = "weights", shared: Path | None = None) -> tuple[Model, dict]:
        """``folder/NAME.pt`` after ``steps`` steps (checkpoints in ``folder/last.pt``)."""
        weights, record = folder / f"{name}.pt", folder / TRAINED
        if not (weights.is_file() and record.is_file()):
            trained = fit_chunk(self.weights_name, start.path, weights, folder / "last.pt", self.chunk,
                                self.cfg.mix_with, self.threads, log, progress,
                                lambda: mixed_sources(self.weights_name, scenes, self.chunk, self.cfg.mix_with, log))
            write_text_atomic(record, json.dumps(trained, indent=1))  # kept for a round resumed after training
        return self.model_at(weights), json.loads(record.read_text())

    def after_training(self, model: Model, round_dir: Path, log: Callable[[str], None]) -> dict | None:
        if self.stage_cfg is None:
            return None
        return stage_of_round(self.target, model.path, round_dir, self.stage_cfg, log)

    def average(self, start: Model, trained: Model, share: float, round_dir: Path) -> Model:
        from ...perception.weights_io import average_weights

        averaged = round_dir / f"{AVERAGED}.pt"
        if not averaged.is_file():
            average_weights(start.path, trained.path, share, averaged)
        return self.model_at(averaged)

    def start_cache(self, start: Model) -> Path:
        """Named by the weights' digest, and their own point stage's when one is beside them (a
        round's weights given as the start)."""
        from ...evaluation import start_evaluations_dir
        from ...generator.run import file_digest
        from ...perception.weights_io import stage_path_of

        stage = stage_path_of(start.path)
        return start_evaluations_dir(file_digest(start.path)[:16] + (f"-{file_digest(stage)[:8]}" if stage.is_file() else ""))

    def log_start(self, start: Model, log: Callable[[str], None]) -> None:
        """One line when the start weights' card says they were trained for another LiDAR than the
        one every round attacks, trains and evaluates with (the shipped preset)."""
        from ...sensors.lidar_spec import DEFAULT_LIDAR
        from ...training.cards import lidar_of_weights

        trained_for = lidar_of_weights(start.path)
        if trained_for not in (None, DEFAULT_LIDAR):
            log(f"{start.path}: trained for the {trained_for!r} LiDAR; every round casts its frames with "
                f"{DEFAULT_LIDAR!r}, so round 0 scores them on another sensor and the rounds tune them to it")


def _card_weights(card_path: Path, given: Path) -> Path:
    """The weights a harden card keeps: its last kept round's (beside the card, a link followed),
    else its start's."""
    card_path = Path(card_path).resolve()
    card = read_json(card_path, "the harden card (asg harden writes OUT/card.json)")
    try:
        card["rounds"][0]  # a card with a finished round
        kept = [r for r in card["rounds"] if is_kept(r)]
        return card_path.parent / kept[-1]["weights"] if kept else Path(card["start"]["weights"])
    except (ValueError, KeyError, IndexError, TypeError, AttributeError):
        raise InputError(f"--weights {given}: not a harden card (card.json) with a finished round") from None
