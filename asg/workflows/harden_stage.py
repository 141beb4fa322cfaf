"""The point stage of a hardening run's rounds: train.yaml's ``point_stage`` block checked before the
run starts, its data set built once the run is claimed, and the stage fitted to each round's weights."""
from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Callable

from sumo_scenarios.atomic import write_text_atomic

from ..perception.targets import Target
from ..training.point_stage_fit import PointStageFitConfig, load_point_stage_config


def stage_config(fit_stage: bool) -> PointStageFitConfig | None:
    """train.yaml's ``point_stage`` block when rounds fit their own stage (``fit_stage``; else
    None); its data set must be built or known (one InputError otherwise: a round would find it
    missing only after its training). :func:`build_stage_set` builds it."""
    from ..dataset_spec import load_spec

    if not fit_stage:
        return None
    stage_cfg = load_point_stage_config()
    if not stage_set_built(stage_cfg):
        load_spec(stage_cfg.dataset)  # known, or one InputError
    return stage_cfg


def stage_set_built(stage_cfg: PointStageFitConfig) -> bool:
    from ..datasets import dataset_path

    name = stage_cfg.dataset
    return (Path(name) / "index.json").is_file() or (dataset_path(name) / "index.json").is_file()


def build_stage_set(stage_cfg: PointStageFitConfig | None) -> None:
    """The point stage's data set built if it is not yet (minutes of traffic simulation: after the
    run's settings are checked and its folder claimed, before the first round)."""
    from ..datasets import build_dataset

    if stage_cfg is not None and not stage_set_built(stage_cfg):
        build_dataset(stage_cfg.dataset)


def stage_of_round(target: Target, weights: Path, round_dir: Path, stage_cfg: PointStageFitConfig,
                   log: Callable[[str], None]) -> dict:
    """The point stage fitted to a round's ``weights`` of the shipped model ``target``
    (asg.training.point_stage_fit.fit_stage_beside
    with ``stage_cfg``, train.yaml's ``point_stage`` block, on the frozen weights), written beside
    them, where every detector built from the file finds it; the fit's record, kept in the round's
    folder (``STEM.stage.json``) so that a resumed round neither fits it again nor loses the record.
    The fit resumes from its checkpoint in ``round_dir/stage-fit-STEM``."""
    from ..perception.weights_io import stage_path_of
    from ..training.point_stage_fit import fit_stage_beside

    record = round_dir / f"{weights.stem}.stage.json"
    if stage_path_of(weights).is_file() and record.is_file():
        return json.loads(record.read_text())
    log(f"fitting a point stage to {weights} ...")
    _, fitted = fit_stage_beside(target.name, weights, round_dir / f"stage-fit-{weights.stem}", log, fit_config=stage_cfg)
    write_text_atomic(record, json.dumps(fitted, indent=1))
    shutil.rmtree(round_dir / f"stage-fit-{weights.stem}", ignore_errors=True)
    return fitted
