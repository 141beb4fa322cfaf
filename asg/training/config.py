"""Which weights each fusion model uses and how they are trained (configs/detectors/train.yaml)."""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Literal

from sumo_scenarios.errors import InputError
from sumo_scenarios.paths import configs_dir
from sumo_scenarios.strict import from_mapping, read_yaml

from .branch_fit import BranchFitConfig
from ..perception.data import Augmentation
from ..scene.views import Views
from ..sensors.lidar_spec import DEFAULT_LIDAR

def weights_for(fusion: str) -> str:
    """The shipped weights name behind ``fusion`` (none and late share 'single'); InputError for a
    plugin or an unknown name (asg.perception.fusion.shipped_model)."""
    from ..perception.targets import shipped_model

    return shipped_model(fusion).weights


@dataclass(frozen=True)
class TrainConfig:
    dataset: str = "detector-train"
    steps: int = 4000
    batch_size: int = 4
    lr: float = 0.002
    weight_decay: float = 0.0001
    #: "step": lr x0.1 at each fraction in decay_at; "onecycle": warm up to lr over pct_start of
    #: the steps (from lr / div_factor), then cosine annealing (Adam's beta1 cycled 0.95 <-> 0.85)
    schedule: Literal["step", "onecycle"] = "step"
    decay_at: tuple[float, ...] = (0.7, 0.9)
    pct_start: float = 0.4
    div_factor: float = 10.0
    seed: int = 1
    checkpoint_every: int = 200
    #: fusion models: "ego" trains on each frame as its ego sees it; "all" on each sensing agent's
    #: view in turn (3 times the distinct examples from the same frames)
    views: Views = Views.EGO
    #: the random flip, rotation and scale of each training example (``augment`` in train.yaml)
    augment: Augmentation = Augmentation()
    #: weight of the orientation-aware corner loss (asg.perception.head.corner_loss; 0: off)
    corner_loss: float = 0.0
    #: also every frame of ``dataset`` as its ego receives it in the standard noisy V2X setting
    #: (asg.scene.noisy: each collaborator's pose off, its message 100 ms late), one example a
    #: frame (the ego's view: a collaborator's own view of a noisy frame would mislabel it)
    noisy_links: bool = False
    #: the LiDAR preset (configs/lidar/) the training frames are rendered with: a detector for
    #: another sensor; evaluation, attacks and fine-tuning render with the shipped one (v2xp)
    lidar: str = DEFAULT_LIDAR


@dataclass(frozen=True)
class ChunkConfig(TrainConfig):
    """asg's own trainer's chunk from trained weights on challenging scenes mixed with normal frames
    (the ``asg`` part of train.yaml's ``finetune`` block; a hardening round's is
    asg.workflows.harden.RoundChunkConfig). ``dataset`` is unused: the scenes are the challenging
    set (``--on``) or the round's, the normal frames the train splits of the block's ``mix_with``."""

    #: share of each batch's examples drawn from the challenging scenes; the rest come from
    #: ``mix_with`` (the train split of each, in equal shares)
    challenging_share: float = 0.5
    #: the views of the challenging scenes' examples ("ego": only the attacked one, the view the
    #: attack made hard; None: ``views``, as the normal frames)
    challenging_views: Views | None = None


@dataclass(frozen=True)
class OpenCOODTrainConfig:
    """How OpenCOOD's trainer trains an OpenCOOD model folder (the ``opencood`` part of train.yaml's
    ``finetune`` and ``harden`` blocks; its batch, rate and schedule come from the folder's own
    config.yaml)."""
    #: epochs a fine-tuning or a hardening round trains (one gained on its challenging set and
    #: holdout where three lost per frame on normal-val: docs/results/README.md, OpenCOOD)
    epochs: int = 1


@dataclass(frozen=True)
class FinetuneConfig:
    """``asg finetune`` (train.yaml's ``finetune`` block): what a fine-tuning reads whatever trains
    the target, and each trainer's own settings under the name of its kind
    (asg.perception.targets.Training): ``asg`` for a shipped model, ``opencood`` for an OpenCOOD
    model folder. A trainer reads its own part and no other."""

    #: the data sets whose train splits are trained on beside the challenging scenes
    mix_with: tuple[str, ...] = ("normal", "detector-train")
    #: evaluated before and after (with the challenging val set of the attacked model)
    eval_sets: tuple[str, ...] = ("normal-val", "heuristic")
    asg: ChunkConfig = field(default_factory=ChunkConfig)
    opencood: OpenCOODTrainConfig = field(default_factory=OpenCOODTrainConfig)

    def with_trainer(self, kind: str, **changes) -> "FinetuneConfig":
        """A copy whose part for the trainer of ``kind`` (a Training value) has ``changes``:
        ``cfg.with_trainer("asg", steps=2)``."""
        return replace(self, **{kind: replace(getattr(self, kind), **changes)})


#: the train.yaml block of the branch fit (any weights): ``asg train --fusion F --iou-branch``
IOU_BLOCK = "iou_branch"
#: the train.yaml block of ``asg finetune``
FINETUNE_BLOCK = "finetune"


def load_train_config(weights: str, path: Path | None = None) -> TrainConfig:
    """The training settings of ``weights`` (its train.yaml block), every number checked."""
    return check_train_config(from_mapping(TrainConfig, train_block(weights, path), f"train.yaml:{weights}"),
                              f"train.yaml:{weights}")


def load_finetune_config(path: Path | None = None) -> FinetuneConfig:
    """The fine-tuning settings (train.yaml's ``finetune`` block, or ``path``'s), every number checked."""
    where = f"{path or 'train.yaml'}:{FINETUNE_BLOCK}"
    block = old_form_refused(path, FINETUNE_BLOCK, FinetuneConfig)
    return check_finetune_config(from_mapping(FinetuneConfig, block, where), where)


def _loop_and_asg_settings(loop_type: type) -> tuple[set[str], set[str]]:
    """The names of ``loop_type``'s own settings (a finetune or harden block's top) and of its
    ``asg`` part's (asg's trainer's, which sat at the block's top before it had a part)."""
    fields = loop_type.__dataclass_fields__
    return set(fields) - {"asg", "opencood"}, set(fields["asg"].default_factory.__dataclass_fields__)


def old_form_refused(path: Path | None, name: str, loop_type: type) -> dict:
    """Block ``name`` (``loop_type``'s) of train.yaml or ``path``, refused in one line in the form
    from before each trainer's settings had a part of their own: asg's trainer's settings at the
    block's top (they sit under its ``asg`` part now), or an ``opencood`` block of the file's own
    (now the block's ``opencood`` part)."""
    where = f"{path or 'train.yaml'}:{name}"
    block = train_block(name, path)
    loop, asg = _loop_and_asg_settings(loop_type)
    moved = sorted(k for k in block if k in asg and k not in loop)
    if moved:
        raise InputError(f"{where}: {', '.join(moved)} set asg's own trainer; they sit under the block's asg part "
                         "now (asg: {steps: ..., lr: ...}; configs/detectors/train.yaml)")
    if path is not None and "opencood" in read_yaml(path):
        raise InputError(f"{path}: OpenCOOD's trainer's settings sit in the {name} block's opencood part now "
                         f"({name}: {{opencood: {{epochs: ...}}}}), not in an opencood block of their own")
    return block


def record_in_todays_form(record: dict, loop_type: type) -> dict:
    """A finetune or harden run's run.json written before each trainer's settings had a part of
    their own, in today's form: its ``config`` (``loop_type``'s, flat then) split into the loop's
    settings and asg's trainer's (under ``asg``: every setting of its chunk, the seed included, which
    was the loop's too); OpenCOOD's trainer's settings, once beside the config, under its
    ``opencood``; ``opencood_epochs``, once in the harden block, dropped (the run read the
    ``opencood`` block). A record in today's form is returned as it is."""
    config = record.get("config")
    if not isinstance(config, dict) or "asg" in config:
        return record
    loop, asg = _loop_and_asg_settings(loop_type)
    today = {**{k: v for k, v in config.items() if k in loop}, "asg": {k: v for k, v in config.items() if k in asg}}
    rest = {k: v for k, v in record.items() if k != "opencood"}
    if isinstance(record.get("opencood"), dict):
        today["opencood"] = record["opencood"]
    return {**rest, "config": today}


def check_finetune_config(cfg: FinetuneConfig, where: str) -> FinetuneConfig:
    """``cfg`` (a finetune block, or a harden block) if its sets and each trainer's part are in range
    (one InputError naming the first that is not)."""
    from sumo_scenarios import checks

    from ..dataset_spec import check_train_source

    check_train_config(cfg.asg, f"{where}.asg")
    checks.number(cfg.opencood.epochs, f"{where}.opencood.epochs", 1, 1000)
    for name in cfg.mix_with:
        check_train_source(name, f"{where}.mix_with")
    for name in cfg.eval_sets:
        checks.safe_id(name, f"{where}.eval_sets: data set")
    if cfg.asg.challenging_share < 1.0 and not cfg.mix_with:
        raise InputError(f"{where}: asg.challenging_share below 1 needs sets in mix_with")
    return cfg


def check_train_config(cfg: TrainConfig, where: str):
    """``cfg`` if every setting is in range (one InputError naming the first that is not): at
    least one step, example and checkpoint interval; a learning rate in (0, 1]; weight decay in
    [0, 1]; schedule fractions in (0, 1); a seed of 0 or more; a rotation of
    at most 180 deg and a scale of at most 0.5 in the augmentation; a corner-loss weight in [0, 100]; a
    LiDAR preset that exists (a fine-tuning chunk: only the shipped one, the sensor its scenes are
    attacked and evaluated with, and a share in [0, 1]). Checked when loaded, before any work."""
    from sumo_scenarios import checks

    from ..sensors.lidar_spec import load_lidar_spec

    checks.number(cfg.steps, f"{where}.steps", 1, 10_000_000)
    checks.number(cfg.batch_size, f"{where}.batch_size", 1, 1024)
    checks.number(cfg.lr, f"{where}.lr", 0.0, 1.0, lo_open=True)
    checks.number(cfg.weight_decay, f"{where}.weight_decay", 0.0, 1.0)
    checks.number(cfg.pct_start, f"{where}.pct_start", 0.0, 1.0, lo_open=True)
    checks.number(cfg.div_factor, f"{where}.div_factor", 0.0, 1e6, lo_open=True)
    checks.number(cfg.seed, f"{where}.seed", 0, 2**32 - 1)
    checks.number(cfg.checkpoint_every, f"{where}.checkpoint_every", 1, 10_000_000)
    for f in cfg.decay_at:
        checks.number(f, f"{where}.decay_at", 0.0, 1.0, lo_open=True)
    checks.number(cfg.augment.rotate_deg, f"{where}.augment.rotate_deg", 0.0, 180.0)
    checks.number(cfg.augment.scale, f"{where}.augment.scale", 0.0, 0.5)
    checks.number(cfg.corner_loss, f"{where}.corner_loss", 0.0, 100.0)
    if cfg.pct_start >= 1.0:
        raise InputError(f"{where}.pct_start: {cfg.pct_start:g} leaves no steps to anneal; give a fraction below 1")
    checks.safe_id(cfg.lidar, f"{where}.lidar")
    load_lidar_spec(cfg.lidar)
    if isinstance(cfg, ChunkConfig):
        if cfg.lidar != DEFAULT_LIDAR:
            raise InputError(f"{where}.lidar: fine-tuning renders with the LiDAR its scenes are attacked and evaluated "
                             f"with ({DEFAULT_LIDAR}); '{cfg.lidar}' applies to asg train's blocks only")
        checks.number(cfg.challenging_share, f"{where}.challenging_share", 0.0, 1.0)
    return cfg


def load_branch_config(path: Path | None = None) -> BranchFitConfig:
    """The settings of the IoU and refinement branches' fit (train.yaml's ``iou_branch`` block)."""
    return from_mapping(BranchFitConfig, train_block(IOU_BLOCK, path), f"train.yaml:{IOU_BLOCK}")


def train_block(name: str, path: Path | None) -> dict:
    """Block ``name`` of train.yaml (or of ``path``): a mapping, or one line of InputError."""
    where = path or configs_dir() / "detectors" / "train.yaml"
    data = read_yaml(where)
    if not isinstance(data, dict):
        raise InputError(f"{where}: expected a mapping of training blocks (name: settings), got "
                         f"{type(data).__name__ if data is not None else 'an empty file'}")
    if name not in data:
        raise InputError(f"{where}: no training block '{name}'")
    if not isinstance(data[name], dict):
        raise InputError(f"{where}: the '{name}' block must be a mapping of settings (key: value), "
                         f"got {type(data[name]).__name__ if data[name] is not None else 'nothing'}")
    return data[name]
