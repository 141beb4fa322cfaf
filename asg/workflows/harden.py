"""``asg harden --fusion F --rounds R``: iterated adversarial training, and its controls.

Each round k = 1..R, into ``OUT/round-k/`` (resumable stage by stage; a finished round is a row
of ``OUT/card.json`` and is never run again):

1. **scenes**: ``scenes_per_round`` fresh training scenes: a seeded shuffle of the train splits of
   the ``pool`` sets (never a val or held-out set), round k taking the k-th slice, so no scene is
   used twice;
2. **data** (``--data``, the hardening or a control at equal compute):
   ``adversarial``: the generator (ACS + APS, configs/generate.yaml, ``--space`` if given) run
   against the current weights on those scenes; ``random``: the same scenes with one uniformly
   drawn plausible perturbation each (the same space, plausibility level and movers, no search);
   ``normal``: the scenes as they are (more normal frames);
3. **train**: the target's trainer (asg.workflows.trainers, with its part of train.yaml's
   ``harden`` block) trains the current model on this round's scenes (and, with ``keep_previous``,
   every earlier round's) beside the train splits of ``mix_with`` (against forgetting): asg's
   trainer one chunk into ``round-k/weights.pt``, OpenCOOD's a few epochs into ``round-k/model``;
4. **evaluate** on fixed sets: ``eval_sets``, ``challenging-F-val`` (the val split attacked against
   the original model) and, with ``noisy``, normal-val under the standard noisy V2X setting
   (asg.scene.noisy); with ``reattack``, the paper's protocol run on normal-val against the
   round's weights (the original's own attack is challenging-F-val), and the weights the round
   started from scored on those scenes too (the card's ``reattack.started_from``).

Round 0 of the card is the start weights on the same evaluation. ``OUT/run.json`` records the
settings: a rerun with other settings is refused (``force`` starts over).
"""
from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable, Literal, get_args

import numpy as np

from sumo_scenarios.atomic import write_text_atomic
from sumo_scenarios.errors import InputError
from sumo_scenarios.paths import runs_dir
from sumo_scenarios.strict import from_mapping

from . import MAX_ROUNDS
from .harden_rounds import (NOISY_SET, REATTACK_EVAL, STARTED_FROM, evaluate_round, evaluated_set,  # noqa: F401
                            load_scenes, noisy_val_set, reattack_round, round_data, save_scenes,
                            started_from_on_reattack, upgraded_rounds)  # (this module's API too: scripts, tests)
from .random_control import ATTACK_SEED  # noqa: F401  (this module's API too)
from .challenging import own_val_set
from .trainers import Model, round_trainer
from .trainers.base import AVERAGED, is_kept  # (is_kept: this module's API too)
from ..io.run_record import claim, with_defaults
from ..perception.targets import Target
from ..training.config import (ChunkConfig, FinetuneConfig, check_finetune_config, old_form_refused,
                               record_in_todays_form, train_block)
from ..scene import Scene

#: the train.yaml block of ``asg harden``
HARDEN_BLOCK = "harden"
#: what a round trains on (``--data``, the harden block's ``data``)
DataKind = Literal["adversarial", "random", "normal"]
DATA_KINDS: tuple[str, ...] = get_args(DataKind)


@dataclass(frozen=True)
class RoundChunkConfig(ChunkConfig):
    """asg's own trainer's chunk a hardening round (the ``asg`` part of train.yaml's ``harden``
    block): a fine-tuning chunk whose challenging scenes are the round's, and its point stage."""

    #: fit a point stage to each round's weights (and to their average when the guard averages them),
    #: beside them (``round-k/weights.stage.pt``; train.yaml's ``point_stage`` block), so that the
    #: round refines its own boxes rather than with the stage of the model it started from
    #: (docs/harden.md, the point stage); False: every round uses its start's stage
    fit_stage: bool = True


@dataclass(frozen=True)
class HardenConfig(FinetuneConfig):
    """train.yaml's ``harden`` block: what each round attacks, evaluates and guards, read whatever
    trains the target, and each trainer's own settings under its kind (``asg``: asg's trainer's
    chunk a round, :class:`RoundChunkConfig`; ``opencood``: OpenCOOD's epochs a round)."""

    asg: RoundChunkConfig = field(default_factory=RoundChunkConfig)
    #: the seed of the pool's order (each round's slice of fresh scenes)
    seed: int = 1
    scenes_per_round: int = 219
    #: data sets whose train split gives each round fresh scenes
    pool: tuple[str, ...] = ("normal", "detector-train")
    data: DataKind = "adversarial"
    #: a round trains on every earlier round's scenes too (each label an equal part of the share)
    keep_previous: bool = True
    #: evaluate under the standard noisy V2X setting too
    noisy: bool = True
    #: attack each round's weights again on normal-val (the paper's protocol)
    reattack: bool = True
    #: a set no round trains on (a town none of the training sets holds): a round whose AP@0.7 on it
    #: falls below the weights it started from (the whole 95 % interval of the gap under zero) is
    #: not kept; the next round starts from the weights before it. None: every round is kept
    guard_set: str | None = "holdout"
    #: a round the guard would not keep is averaged with the weights it started from, this share of
    #: the round's weights (docs/harden.md, the guard), and kept if the guard keeps the average;
    #: None: dropped as it is
    guard_average: float | None = 0.5


def load_harden_config(path: Path | None = None, **overrides) -> HardenConfig:
    """train.yaml's ``harden`` block (or ``path``'s), then non-None ``overrides``; checked."""
    from sumo_scenarios import checks

    from ..dataset_spec import check_train_source

    where = f"{path or 'train.yaml'}:{HARDEN_BLOCK}"
    data = dict(old_form_refused(path, HARDEN_BLOCK, HardenConfig))
    data.update({k: v for k, v in overrides.items() if v is not None})
    cfg = check_finetune_config(from_mapping(HardenConfig, data, where), where)
    checks.number(cfg.seed, f"{where}.seed", 0, 2**32 - 1)
    checks.number(cfg.scenes_per_round, f"{where}.scenes_per_round", 1, 100_000)
    if cfg.guard_average is not None and not (isinstance(cfg.guard_average, (int, float)) and 0.0 < cfg.guard_average < 1.0):
        raise InputError(f"{where}.guard_average must be a share between 0 and 1 (0.5: half the round's weights) "
                         f"or null, got {cfg.guard_average!r}")
    for name in cfg.pool:
        check_train_source(name, f"{where}.pool")
    if cfg.data not in DATA_KINDS:
        raise InputError(f"--data must be one of {', '.join(DATA_KINDS)}, got {cfg.data!r}")
    if not cfg.pool:
        raise InputError(f"{where}.pool names no data set to draw training scenes from")
    return cfg


def default_out(target: Target, data: str) -> Path:
    """runs/harden/LABEL, or runs/harden/LABEL-DATA for a control."""
    return runs_dir() / "harden" / (target.label if data == "adversarial" else f"{target.label}-{data}")


def harden(target: Target, rounds: int, out: Path | None = None, *, weights: Path | None = None,
           config: HardenConfig | None = None, space: tuple[str, ...] | None = None, executor=None,
           threads: int = 2, force: bool = False, detector_factory: str | None = None,
           config_path: Path | None = None, log: Callable[[str], None] = print,
           progress: Callable[[int, int, float], None] | None = None) -> dict:
    """Run (or resume) ``rounds`` rounds of hardening ``target`` (asg.perception.targets.resolve_target
    gives it from a ``--fusion`` name); returns the card. The target's
    round trainer (asg.workflows.trainers) trains each round; everything else here is the same for
    every kind.

    ``weights``: start from this weights file (or a card: its last round's weights) instead of the
    shipped ones. ``space``: the perturbation spaces the adversarial rounds search (default
    configs/generate.yaml's). ``detector_factory``: stand-in target for the attacks (tests).
    ``config_path``: the ``--config`` file ``config`` came from (None: train.yaml)."""
    if not isinstance(rounds, int) or not 1 <= rounds <= MAX_ROUNDS:
        raise InputError(f"--rounds must be a whole number from 1 to {MAX_ROUNDS}, got {rounds!r}")
    cfg = config or load_harden_config()
    _check_before_starting(cfg, space)
    trainer = round_trainer(target, cfg, threads, config_path)
    trainer.check(weights, train_block(HARDEN_BLOCK, config_path) if config_path else None, train_block(HARDEN_BLOCK, None))
    start = trainer.start(weights)
    out = Path(out) if out is not None else default_out(target, cfg.data)
    pool = _pool(cfg)
    if rounds * cfg.scenes_per_round > len(pool):
        raise InputError(f"{rounds} rounds of {cfg.scenes_per_round} fresh scenes need {rounds * cfg.scenes_per_round}; "
                         f"the pool ({', '.join(cfg.pool)}) holds {len(pool)}: fewer rounds or scenes_per_round")
    settings = {"fusion": target.name, **trainer.settings(start), "config": asdict(cfg),
                "space": list(space) if space else None, "detector": detector_factory}
    claim(out, settings, force, what="a hardening run", as_today=_as_today)
    trainer.prepare()
    card_path = out / "card.json"
    card = json.loads(card_path.read_text()) if card_path.is_file() else {
        "fusion": target.name, "data": cfg.data, "start": {"weights": str(start.path), "sha256": trainer.digest(start)},
        "rounds": []}
    card["rounds"] = upgraded_rounds(card["rounds"])
    trainer.log_start(start, log)
    start_cache = trainer.start_cache(start)  # round 0's evaluations, shared by every run from the same start
    current, current_round = start, 0  # the model the next round starts from, and its round
    own_val = None  # the target's own challenging val set (asg.workflows.challenging.own_val_set)
    for k in range(rounds + 1):
        done = {row["round"]: row for row in card["rounds"]}
        round_dir = out / f"round-{k}"
        if k in done:
            if k and is_kept(done[k]):
                current, current_round = trainer.model_at(out / done[k]["weights"]), k
            continue
        row: dict = {"round": k}
        model = started_from = current
        if k:
            scenes = pool[(k - 1) * cfg.scenes_per_round: k * cfg.scenes_per_round]
            row["data"] = _round_scenes(current, scenes, cfg, space, round_dir, executor, detector_factory, log)
            first = {f"round-{j}": load_scenes(out / f"round-{j}" / "scenes")
                     for j in (range(1, k + 1) if cfg.keep_previous else [k])}
            model, row["trained"] = trainer.train(current, first, round_dir, log, progress, shared=out)
            _after_training(trainer, model, round_dir, row, log)
            row["weights"] = str(model.path.relative_to(out))
        log(f"round {k}: evaluating {model.path} ...")
        cache = _eval_cache(out, k, model, start_cache)
        own_val = own_val or own_val_set(target, executor, log)  # built once, before the first evaluation
        row["evaluation"] = evaluate_round(model, own_val, cfg, cache, executor, log)
        if k and cfg.guard_set is not None:
            before = _eval_cache(out, current_round, current, start_cache)  # evaluated again if gone (another data root)
            evaluated_set(current, cfg.guard_set, cfg.guard_set, before, True, executor, log)
            row["guard"] = guard(before, cache, cfg.guard_set)
            if not row["guard"]["kept"] and cfg.guard_average:
                _log_guard(log, k, row["guard"], "its weights are averaged with the ones it started from")
                model = _averaged_round(trainer, own_val, row, (current, before), model, out, k, executor, log)
            if not row["guard"]["kept"]:
                _log_guard(log, k, row["guard"], "its weights are not kept; the next round starts from "
                           f"{f'round {current_round}' if current_round else 'the start weights'}")
        if k and is_kept(row):
            current, current_round = model, k
        if cfg.reattack:
            own_set = k == 0 and trainer.is_own_start(start)  # the target's own attack exists
            row["reattack"] = reattack_round(None if own_set else model, own_val, round_dir / "reattack", executor,
                                             detector_factory, log, row["evaluation"])
            if k:
                row["reattack"][STARTED_FROM] = started_from_on_reattack(started_from, model, round_dir, executor, log)
        card["rounds"].append(row)
        card["weights"] = str(current.path.relative_to(out)) if current_round else str(start.path)
        write_text_atomic(card_path, json.dumps(card, indent=1))
    return card


def _as_today(record: dict) -> dict:
    """A run.json written before today's settings, as today's code would write it: in today's form
    (asg.training.config.record_in_todays_form), and a setting added since taking the default that
    reproduces what the run did (a run from before rounds fitted their own point stage did not)."""
    defaults = asdict(HardenConfig())
    defaults["asg"]["fit_stage"] = False
    return with_defaults(record_in_todays_form(record, HardenConfig), {"config": defaults, "point_stage": None})


def _after_training(trainer, model, round_dir: Path, row: dict, log: Callable[[str], None]) -> None:
    """What the trainer gives a trained or averaged model before it is evaluated (a point stage),
    recorded in the round's ``row`` under "stage"."""
    stage = trainer.after_training(model, round_dir, log)
    if stage is not None:
        row["stage"] = stage


def _check_before_starting(cfg: HardenConfig, space: tuple[str, ...] | None) -> None:
    """What a round would refuse only after round 0's evaluation, refused now, before the run
    folder is claimed: the spaces the attack searches and the evaluation sets."""
    from ..datasets import check_set_name
    from ..search import SpaceConfig

    if space:
        SpaceConfig(kinds=tuple(space))
    for set_name in cfg.eval_sets:
        check_set_name(set_name)
    if cfg.guard_set is not None:
        check_set_name(cfg.guard_set)
        if cfg.guard_set in {*cfg.pool, *cfg.mix_with}:
            raise InputError(f"train.yaml:{HARDEN_BLOCK}.guard_set '{cfg.guard_set}' is trained on (pool or mix_with); "
                             "give a set no round trains on, e.g. holdout")


def _log_guard(log: Callable[[str], None], k: int, gap: dict, outcome: str) -> None:
    log(f"round {k}: AP@0.7 on {gap['set']} (no round trains on it) fell by {-100 * gap['gap']:.1f} points, "
        f"95 % interval [{100 * gap['low']:+.1f}, {100 * gap['high']:+.1f}]: {outcome}")


def _averaged_round(trainer, own_val: str, row: dict, start: tuple, trained, out: Path, k: int, executor,
                    log: Callable[[str], None]):
    """The guard's cure for a round it would not keep: the round's model averaged with the one it
    started from (``start``: that model and its evaluations' cache; ``cfg.guard_average`` of the round's, the
    trainer's ``average``), given what the trainer gives a trained model (a point stage),
    evaluated and guarded in its turn. ``row`` is updated to the averaged model; what the round
    trained stays under its "unaveraged" key. Returns the averaged model."""
    cfg, (current, before_cache) = trainer.cfg, start
    averaged = trainer.average(current, trained, cfg.guard_average, out / f"round-{k}")
    row["unaveraged"] = {"weights": row["weights"], "evaluation": row["evaluation"], "guard": row["guard"],
                         **({"stage": row["stage"]} if "stage" in row else {})}
    _after_training(trainer, averaged, out / f"round-{k}", row, log)
    log(f"round {k}: evaluating {averaged.path} ({cfg.guard_average:g} of the round's weights) ...")
    row["weights"] = str(averaged.path.relative_to(out))
    cache = _eval_cache(out, k, averaged)
    row["evaluation"] = evaluate_round(averaged, own_val, cfg, cache, executor, log)
    row["guard"] = guard(before_cache, cache, cfg.guard_set) | {
        "averaged": cfg.guard_average}
    return averaged


def _eval_cache(out: Path, k: int, model, start_cache: Path | None = None) -> Path:
    """Where round ``k``'s evaluations are cached: the round's folder (``eval``, or ``eval-averaged``
    for its averaged model), but for round 0 (the start) ``start_cache``, the trainer's cache of the
    start (asg.evaluation.start_evaluations_dir), shared by every run (and control) that starts from
    the same model with the same code."""
    if k:
        return out / f"round-{k}" / ("eval" if model.path.stem != AVERAGED else f"eval-{AVERAGED}")
    return start_cache


def guard(before_cache: Path, after_cache: Path, guard_set: str) -> dict:
    """{"set", "threshold", "gap", "low", "high", "frames", "kept"}: the AP@0.7 gap on ``guard_set``
    of a round's weights over the weights it started from (their evaluations' cached matches),
    paired bootstrap; kept unless the whole 95 % interval is below zero (``ApGap.not_worse``)."""
    from ..objective.paired import load_matches, paired_ap_gap

    gap = paired_ap_gap(load_matches(before_cache / f"{guard_set}.matches.npz"),
                        load_matches(after_cache / f"{guard_set}.matches.npz"), 0.7)
    return gap.guard_record(guard_set)


def _pool(cfg: HardenConfig) -> list[Scene]:
    """Every train-split scene of the pool sets, in a seeded order (the rounds' slices)."""
    from ..datasets import build_dataset, dataset_path, iter_frames, unique_ids

    for name in cfg.pool:
        if not (dataset_path(name) / "index.json").is_file():
            build_dataset(name)
    # ids repeat across a set's logs (the same town, seed and time at two densities) and across
    # sets: a repeat gets a suffix, so that each scene has its own folder
    scenes = list(unique_ids((s for name in cfg.pool for s in iter_frames(name, "train")), separator="_"))
    order = np.random.default_rng([cfg.seed, 7]).permutation(len(scenes))
    return [scenes[int(i)] for i in order]


def _round_scenes(model: Model, scenes: list[Scene], cfg: HardenConfig, space, round_dir: Path,
                  executor, detector_factory: str | None, log: Callable[[str], None]) -> dict:
    """Make (or find) the round's training scenes, ``round_dir/scenes/``, and return the record of
    how they were made (``round_dir/data.json``). A round whose scenes and record are both on disk
    does not make them again: a run folder copied to another machine (say, a committed one without
    its attack folder) resumes at its training."""
    folder, record = round_dir / "scenes", round_dir / "data.json"
    if (folder / ".complete").is_file() and record.is_file():
        return json.loads(record.read_text())
    made, data = round_data(model, scenes, cfg, space, round_dir / "attack", executor, detector_factory, log)
    save_scenes(made, folder)
    write_text_atomic(record, json.dumps(data, indent=1))
    return data
