"""OpenCOOD's own trainer as a hardening round's (asg.workflows.trainers.base): the round's scenes
and the train splits of ``mix_with`` exported in the OPV2V layout OpenCOOD reads (``asg export
--format opv2v``, each group's scenario folders prefixed with its label), normal-val beside them for
the trainer's validation loss, then ``round-k/model``: the start folder's config and checkpoint,
trained ``epochs`` more epochs (the ``opencood`` part of train.yaml's harden or finetune block) by
OpenCOOD's ``tools/train.py``
(asg.perception.opencood.trainer: resumable, it saves every epoch). The round's model is run as
``opencood:OUT/round-k/model``; the guard's average is a folder of its own (the two checkpoints'
tensors averaged, the trained one's config)."""
from __future__ import annotations

import hashlib
import json
import shutil
from dataclasses import replace
from pathlib import Path
from typing import Callable

from sumo_scenarios.atomic import atomic_dir, write_text_atomic
from sumo_scenarios.errors import InputError

from ...perception.targets import Training
from .base import AVERAGED, ROUND_TRAINERS, TRAINED, Model, RoundTrainer

#: the set the trainer validates on (its validation loss), exported once a run
VAL_SET = "normal-val"


@ROUND_TRAINERS.register(Training.OPENCOOD.value)
class OpenCOODRoundTrainer(RoundTrainer):
    """An OpenCOOD model folder, trained by OpenCOOD's trainer with the block's ``opencood`` part
    (asg.training.config.OpenCOODTrainConfig)."""

    def __init__(self, target, cfg, threads: int = 2, config_path: Path | None = None):
        super().__init__(target, cfg, threads, config_path)
        self.train_cfg = cfg.opencood

    def check(self, weights: Path | None, given: dict | None, shipped: dict) -> None:
        """The block, then the settings OpenCOOD's trainer reads from the folder's config.yaml
        (train_params, loss, optimizer, lr_scheduler), then the start."""
        from ...perception.opencood.folder import read_hypes
        from ...perception.opencood.training_settings import check_trainable

        super().check(weights, given, shipped)
        folder = self.target.model_dir
        check_trainable(read_hypes(folder), folder / "config.yaml")
        if weights is not None:
            raise InputError("--weights applies to asg's own models; an OpenCOOD model starts from its folder's "
                             "checkpoint (a further round of a run: --fusion opencood:OUT/round-K/model)")

    def start(self, weights: Path | None) -> Model:
        return self.model_at(self.target.model_dir)

    def is_own_start(self, start: Model) -> bool:
        return True  # the folder as given: its own attack is its challenging val set

    def model_at(self, path: Path) -> Model:
        return Model(self.target.at(Path(path)), None, Path(path))

    def digest(self, model: Model) -> dict[str, str]:
        """{"config", "checkpoint": each file's sha256}."""
        from ...generator.run import file_digest

        return {k: file_digest(p) for k, p in model.target.model_files().items()}

    def settings(self, start: Model) -> dict:
        return {"start": self.digest(start)}

    def prepare(self) -> None:
        """Nothing: the exports a round trains on are made by the round (:meth:`train`)."""

    def train(self, start: Model, scenes: dict[str, list], folder: Path, log: Callable[[str], None],
              progress, name: str = "weights", shared: Path | None = None) -> tuple[Model, dict]:
        """``folder/model`` (whatever ``name``), trained on the export ``folder/train``; normal-val
        exported to ``shared/val`` (default ``folder/val``)."""
        from ...datasets import build_dataset, dataset_path, iter_frames, scenes_of
        from ...perception.opencood.trainer import TRAIN_LOG, run_trainer, seed_from

        record = folder / TRAINED
        if record.is_file() and (folder / "model" / "config.yaml").is_file():
            return self.model_at(folder / "model"), json.loads(record.read_text())
        groups = {label: s for label, s in scenes.items() if s}
        for mix in self.cfg.mix_with:
            if not (dataset_path(mix) / "index.json").is_file():
                log(f"building data set {mix} ...")
                build_dataset(mix)
            groups[mix] = list(iter_frames(mix, "train"))
        train, val, model = folder / "train", (shared or folder) / "val", folder / "model"
        export_opv2v(train, groups, log)
        export_opv2v(val, {"": list(scenes_of(VAL_SET))}, log)
        seed_from(model, start.path, train, val, self.train_cfg.epochs)
        log(f"training {model} with OpenCOOD's trainer ({self.train_cfg.epochs} epochs; its log: {model / TRAIN_LOG}) ...")
        run_trainer(model)
        trained = {"trainer": Training.OPENCOOD.value, "epochs": self.train_cfg.epochs,
                   "examples": {label: len(s) for label, s in groups.items()}, "mix_with": list(self.cfg.mix_with)}
        write_text_atomic(record, json.dumps(trained, indent=1))
        return self.model_at(model), trained

    def after_training(self, model: Model, round_dir: Path, log: Callable[[str], None]) -> dict | None:
        """Nothing: an OpenCOOD model has no point stage to fit."""
        return None

    def average(self, start: Model, trained: Model, share: float, round_dir: Path) -> Model:
        """``round_dir/averaged``: the trained folder's config and its checkpoint's tensors averaged
        with the start's, under the trained checkpoint's name (its epoch)."""
        from ...perception.opencood.folder import checkpoint_of
        from ...perception.weights_io import average_weights

        folder = round_dir / AVERAGED
        if not (folder / ".complete").is_file():
            last = checkpoint_of(trained.path)
            with atomic_dir(folder) as work:
                shutil.copyfile(trained.path / "config.yaml", work / "config.yaml")
                average_weights(checkpoint_of(start.path), last, share, work / last.name)
                (work / ".complete").write_text("")
        return self.model_at(folder)

    def start_cache(self, start: Model) -> Path:
        """Named by the digest of the folder's config and checkpoint."""
        from ...evaluation import start_evaluations_dir

        h = hashlib.sha256()
        for name, digest in sorted(self.digest(start).items()):
            h.update(name.encode() + b"\0" + digest.encode())
        return start_evaluations_dir(f"{self.target.kind}-{h.hexdigest()[:16]}")


def export_opv2v(folder: Path, groups: dict[str, list], log: Callable[[str], None]) -> None:
    """``folder`` in the OPV2V layout: every scene of each group, its scenario folder prefixed with the
    group's name (``NAME-``; none for ``""``); written whole (a stopped export is made again)."""
    if (folder / ".complete").is_file():
        return
    from ...io.export import EXPORT_FORMATS

    log(f"exporting {sum(map(len, groups.values()))} scenes to {folder} (OPV2V layout) ...")
    with atomic_dir(folder) as work:
        writer = EXPORT_FORMATS.entry("opv2v")(work, None)
        for prefix, scenes in groups.items():
            for scene in scenes:
                writer.write(replace(scene, scene_id=f"{prefix}-{scene.scene_id}" if prefix else scene.scene_id))
        writer.close()
        (work / ".complete").write_text("")
