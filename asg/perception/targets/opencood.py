"""An OpenCOOD model folder (``--fusion opencood:DIR``): run through OpenCOOD's own pre-processing,
model and post-processing (asg.perception.opencood), trained by OpenCOOD's own trainer."""
from __future__ import annotations

import re
from pathlib import Path

from sumo_scenarios.digest import file_digest, files_digest
from sumo_scenarios.errors import InputError

from ...registry import TARGET_PREFIXES, prefixed_kind
from ..fusion import has_own_attention
from .base import TARGET_KINDS, Target, Training, shipped_list

KIND = "opencood"


@TARGET_KINDS.register(KIND)
class OpenCOODTarget(Target):
    order = 0  # a prefixed name is its prefix's, whatever else it spells
    prefixed = True
    training = Training.OPENCOOD
    header = "OpenCOOD model folders"
    has_reference_pipeline = True
    own_ground_truth = True

    @classmethod
    def claims(cls, name: str) -> bool:
        return prefixed_kind(name) == KIND

    @classmethod
    def help_names(cls) -> list[str]:
        return [f"{TARGET_PREFIXES[KIND].prefix}DIR"]

    @classmethod
    def name_of(cls, folder: Path) -> str:
        """The ``--fusion`` name of a model folder (``opencood:FOLDER``)."""
        return f"{TARGET_PREFIXES[KIND].prefix}{folder}"

    def at(self, folder: Path) -> "OpenCOODTarget":
        """The model folder ``folder`` (another round's) as a target of this kind."""
        return type(self)(self.name_of(folder))

    @property
    def model_dir(self) -> Path:
        """The model folder; InputError if it is empty or not a folder."""
        from ..opencood import model_dir_of

        return model_dir_of(self.name)

    @property
    def label(self) -> str:
        """The folder's name and the first 8 hex digits of the sha256 of its config and checkpoint,
        so that another model, or the same folder retrained, gets its own."""
        stem = re.sub(r"[^A-Za-z0-9_-]+", "_", self.model_dir.resolve().name)[:40].strip("_-") or "model"
        return f"opencood-{stem}-{files_digest(self.model_files().values())[:8]}"

    def model_files(self) -> dict[str, Path]:
        """{"config": config.yaml, "checkpoint": the checkpoint OpenCOOD loads}."""
        from ..opencood import model_files

        return model_files(self.model_dir)

    def detector(self, weights_file: str | None = None, **options):
        from ..opencood import build_opencood_detector

        self._no_options(options)
        if weights_file:
            raise InputError(f"--weights applies to the shipped models; '{self.name}' loads its folder's checkpoint")
        return build_opencood_detector(self.name)

    @property
    def own_attention(self) -> bool:
        return has_own_attention(self.detector())

    def run_record(self) -> dict:
        return {"opencood_sha256": {k: file_digest(p) for k, p in self.model_files().items()}}

    def evaluation_note(self) -> str:
        from ..opencood.limits import post_processor_note

        return post_processor_note()

    def not_trained_here(self) -> str:
        return (f"'{self.name}' is an OpenCOOD model: OpenCOOD's own trainer trains it, through asg finetune and "
                f"asg harden (docs/opencood.md); asg train trains the shipped models ({shipped_list()})")
