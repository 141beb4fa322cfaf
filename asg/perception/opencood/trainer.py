"""OpenCOOD's own trainer (``opencood/tools/train.py``, unmodified) on asg's exported scenes: a model
folder seeded from a trained one (its config with new data folders and more epochs, its latest
checkpoint), then trained in this process after asg's runtime preparation (runtime.py), which
``python -m opencood.tools.train`` lacks. The trainer saves ``net_epochN.pth`` after each epoch and,
run again on the folder, resumes from the highest N (its optimizer restarts, as OpenCOOD's own resume
does)."""
from __future__ import annotations

import contextlib
import runpy
import shutil
import sys
from pathlib import Path

import yaml

from sumo_scenarios.atomic import write_text_atomic

from .folder import HypesLoader, checkpoint_of, read_hypes
from .runtime import opencood

#: the trainer's log in a model folder (appended to: a resumed run adds to it)
TRAIN_LOG = "train.log"


def epoch_of(checkpoint: Path) -> int:
    """N of ``net_epochN.pth``; 1 for ``latest.pth`` (seeded as ``net_epoch1.pth``: OpenCOOD's trainer
    takes a ``latest.pth`` as epoch 100 and would train no further)."""
    digits = checkpoint.stem.removeprefix("net_epoch")
    return int(digits) if checkpoint.stem.startswith("net_epoch") and digits.isdigit() else 1


def seed_from(model_dir: Path, source: Path, train: Path, val: Path, more_epochs: int) -> None:
    """A new ``model_dir`` from the trained folder ``source``: its config (``root_dir`` and
    ``validate_dir`` replaced, ``more_epochs`` added to its epochs) and its checkpoint; nothing done
    if ``model_dir`` already has a config (a resumed fine-tuning)."""
    if (model_dir / "config.yaml").is_file():
        return
    read_hypes(source)  # one line for a folder OpenCOOD's adapter would refuse
    last = checkpoint_of(source)
    hypes = yaml.load((source / "config.yaml").read_text(encoding="utf-8"), Loader=HypesLoader)
    hypes = yaml.safe_load(yaml.safe_dump(hypes))
    hypes.update(root_dir=str(Path(train).resolve()), validate_dir=str(Path(val).resolve()))
    epoch = epoch_of(last)
    hypes["train_params"]["epoches"] = epoch + more_epochs
    model_dir.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(last, model_dir / f"net_epoch{epoch}.pth")
    write_text_atomic(model_dir / "config.yaml", yaml.safe_dump(hypes, sort_keys=False))


def run_trainer(model_dir: Path) -> None:
    """OpenCOOD's ``tools/train.py --hypes_yaml model_dir/config.yaml --model_dir model_dir`` in this
    process, its output appended to ``model_dir/train.log``."""
    opencood()  # box_overlaps compiled, get_cmap restored: the trainer imports as shipped
    argv = sys.argv
    sys.argv = ["opencood.tools.train", "--hypes_yaml", str(model_dir / "config.yaml"), "--model_dir", str(model_dir)]
    try:
        with open(model_dir / TRAIN_LOG, "a", buffering=1) as log, contextlib.redirect_stdout(log):
            runpy.run_module("opencood.tools.train", run_name="__main__")
    finally:
        sys.argv = argv
