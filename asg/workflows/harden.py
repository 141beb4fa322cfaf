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
3. **train**: one chunk from the current weights on batches that mix this round's scenes (and, with
   ``keep_previous``, every earlier round's) with the train splits of ``mix_with`` (against
   forgetting), train.yaml's ``harden`` block; writes ``round-k/weights.pt``;
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
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable, Literal, get_args

import numpy as np

from sumo_scenarios.atomic import write_text_atomic
from sumo_scenarios.errors import InputError
from sumo_scenarios.paths import runs_dir
from sumo_scenarios.strict import from_mapping

from . import MAX_ROUNDS
from .finetune import fit_chunk, mixed_sources
from .harden_stage import build_stage_set, stage_config, stage_of_round
from .harden_rounds import (NOISY_SET, REATTACK_EVAL, STARTED_FROM, evaluate_round, evaluated_set,  # noqa: F401
                            load_scenes, noisy_val_set, reattack_round, round_data, save_scenes,
                            started_from_on_reattack, upgraded_rounds)  # (this module's API too: scripts, tests)
from .random_control import ATTACK_SEED  # noqa: F401  (this module's API too)
from ..io.run_record import claim, with_defaults
from ..sensors.lidar_spec import DEFAULT_LIDAR
from ..training.cards import lidar_of_weights
from ..training.config import FinetuneConfig, train_block, check_train_config, weights_for
from ..training.point_stage_fit import PointStageFitConfig
from ..perception.weights_io import weights_path
from ..scene import Scene

#: the train.yaml block of ``asg harden``
HARDEN_BLOCK = "harden"
#: what a round trains on (``--data``, the harden block's ``data``)
DataKind = Literal["adversarial", "random", "normal"]
DATA_KINDS: tuple[str, ...] = get_args(DataKind)
#: a round's weights averaged with its start's (the guard's cure), in its folder
AVERAGED_WEIGHTS = "averaged.pt"


@dataclass(frozen=True)
class HardenConfig(FinetuneConfig):
    """train.yaml's ``harden`` block: a fine-tuning chunk per round (FinetuneConfig's fields, the
    round's scenes taking ``challenging_share`` of each batch) and what each round attacks."""

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
    #: fit a point stage to each round's weights (and to their average when the guard averages them),
    #: beside them (``round-k/weights.stage.pt``; train.yaml's ``point_stage`` block), so that the
    #: round refines its own boxes rather than with the stage of the model it started from
    #: (docs/harden.md, the point stage); False: every round uses its start's stage
    fit_stage: bool = True
    #: an OpenCOOD model (--fusion opencood:DIR): the epochs OpenCOOD's trainer fine-tunes it a round
    #: (one gained on its challenging set and holdout where three lost per frame on normal-val:
    #: docs/results/README.md, OpenCOOD)
    opencood_epochs: int = 1


def load_harden_config(path: Path | None = None, **overrides) -> HardenConfig:
    """train.yaml's ``harden`` block (or ``path``'s), then non-None ``overrides``; checked."""
    from sumo_scenarios import checks

    data = dict(train_block(HARDEN_BLOCK, path))
    data.update({k: v for k, v in overrides.items() if v is not None})
    where = f"train.yaml:{HARDEN_BLOCK}"
    cfg = check_train_config(from_mapping(HardenConfig, data, where), where)
    checks.number(cfg.scenes_per_round, f"{where}.scenes_per_round", 1, 100_000)
    checks.number(cfg.opencood_epochs, f"{where}.opencood_epochs", 1, 1000)
    if cfg.guard_average is not None and not (isinstance(cfg.guard_average, (int, float)) and 0.0 < cfg.guard_average < 1.0):
        raise InputError(f"{where}.guard_average must be a share between 0 and 1 (0.5: half the round's weights) "
                         f"or null, got {cfg.guard_average!r}")
    for name in cfg.pool:
        checks.safe_id(name, f"{where}.pool")
    if cfg.data not in DATA_KINDS:
        raise InputError(f"--data must be one of {', '.join(DATA_KINDS)}, got {cfg.data!r}")
    if not cfg.pool:
        raise InputError(f"{where}.pool names no data set to draw training scenes from")
    return cfg


def default_out(fusion: str, data: str) -> Path:
    return runs_dir() / "harden" / (fusion if data == "adversarial" else f"{fusion}-{data}")


def harden(fusion: str, rounds: int, out: Path | None = None, *, weights: Path | None = None,
           config: HardenConfig | None = None, space: tuple[str, ...] | None = None, executor=None,
           threads: int = 2, force: bool = False, detector_factory: str | None = None,
           log: Callable[[str], None] = print, progress: Callable[[int, int, float], None] | None = None) -> dict:
    """Run (or resume) ``rounds`` rounds of hardening ``fusion``; returns the card.

    ``weights``: start from this weights file (or a card: its last round's weights) instead of the
    shipped ones. ``space``: the perturbation spaces the adversarial rounds search (default
    configs/generate.yaml's). ``detector_factory``: stand-in target for the attacks (tests)."""
    if not isinstance(rounds, int) or not 1 <= rounds <= MAX_ROUNDS:
        raise InputError(f"--rounds must be a whole number from 1 to {MAX_ROUNDS}, got {rounds!r}")
    cfg = config or load_harden_config()
    _check_before_starting(cfg, space)
    name = weights_for(fusion)
    start = _start_weights(weights, fusion, name)
    out = Path(out) if out is not None else default_out(fusion, cfg.data)
    from ..generator.run import file_digest

    pool = _pool(cfg)
    if rounds * cfg.scenes_per_round > len(pool):
        raise InputError(f"{rounds} rounds of {cfg.scenes_per_round} fresh scenes need {rounds * cfg.scenes_per_round}; "
                         f"the pool ({', '.join(cfg.pool)}) holds {len(pool)}: fewer rounds or scenes_per_round")
    stage_cfg = stage_config(cfg.fit_stage)
    settings = {"fusion": fusion, "start_weights": str(start), "start_sha256": file_digest(start),
                "config": asdict(cfg), "space": list(space) if space else None, "detector": detector_factory,
                "point_stage": asdict(stage_cfg) if stage_cfg else None}
    # a setting added since a folder was claimed takes the default that reproduces what it did
    # (a run from before rounds fitted their own point stage did not)
    claim(out, settings, force, what="a hardening run",
          as_today=lambda record: with_defaults(record, {"config": asdict(HardenConfig()) | {"fit_stage": False},
                                                         "point_stage": None}))
    build_stage_set(stage_cfg)
    card_path = out / "card.json"
    card = json.loads(card_path.read_text()) if card_path.is_file() else {
        "fusion": fusion, "data": cfg.data, "start": {"weights": str(start), "sha256": settings["start_sha256"]},
        "rounds": []}
    card["rounds"] = upgraded_rounds(card["rounds"])
    _log_start_lidar(start, log)
    current, current_round = start, 0  # the weights the next round starts from, and their round
    shipped_start = settings["start_sha256"] == file_digest(_start_weights(None, fusion, name))
    for k in range(rounds + 1):
        done = {row["round"]: row for row in card["rounds"]}
        round_dir = out / f"round-{k}"
        if k in done:
            if k and is_kept(done[k]):
                current, current_round = out / done[k]["weights"], k
            continue
        row: dict = {"round": k}
        weights = started_from = current
        if k:
            scenes = pool[(k - 1) * cfg.scenes_per_round: k * cfg.scenes_per_round]
            row["data"] = _round_scenes(fusion, current, scenes, cfg, space, round_dir, executor, detector_factory, log)
            first = {f"round-{j}": load_scenes(out / f"round-{j}" / "scenes")
                     for j in (range(1, k + 1) if cfg.keep_previous else [k])}
            weights, record = round_dir / "weights.pt", round_dir / "trained.json"
            if not (weights.is_file() and record.is_file()):
                trained = fit_chunk(name, current, weights, round_dir / "last.pt", cfg, cfg.steps, threads,
                                    log, progress, lambda: mixed_sources(name, first, cfg, log))
                write_text_atomic(record, json.dumps(trained, indent=1))  # kept for a round resumed after training
            row["trained"] = json.loads(record.read_text())
            if stage_cfg:
                row["stage"] = stage_of_round(fusion, weights, round_dir, stage_cfg, log)
            row["weights"] = str(weights.relative_to(out))
        log(f"round {k}: evaluating {weights} ...")
        row["evaluation"] = evaluate_round(fusion, weights, cfg, _eval_cache(out, k, weights), executor, log)
        if k and cfg.guard_set is not None:
            before = _eval_cache(out, current_round, current)  # evaluated again if gone (a resume on another data root)
            evaluated_set(fusion, current, cfg.guard_set, cfg.guard_set, before, True, executor, log)
            row["guard"] = guard(before, _eval_cache(out, k, weights), cfg.guard_set)
            if not row["guard"]["kept"] and cfg.guard_average:
                _log_guard(log, k, row["guard"], "its weights are averaged with the ones it started from")
                weights = _averaged_round(fusion, row, current, current_round, weights, cfg, stage_cfg, out, k,
                                          executor, log)
            if not row["guard"]["kept"]:
                _log_guard(log, k, row["guard"], "its weights are not kept; the next round starts from "
                           f"{f'round {current_round}' if current_round else 'the start weights'}")
        if k and is_kept(row):
            current, current_round = weights, k
        if cfg.reattack:
            own_set = None if k == 0 and shipped_start else weights  # the shipped weights' attack exists
            row["reattack"] = reattack_round(fusion, own_set, round_dir / "reattack", executor,
                                             detector_factory, log, row["evaluation"])
            if k:
                row["reattack"][STARTED_FROM] = started_from_on_reattack(fusion, started_from, weights, round_dir,
                                                                         executor, log)
        card["rounds"].append(row)
        card["weights"] = str(current.relative_to(out)) if current_round else str(start)
        write_text_atomic(card_path, json.dumps(card, indent=1))
    return card


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
        trained_on = {*cfg.pool, *cfg.mix_with, cfg.dataset}
        if cfg.guard_set in trained_on:
            raise InputError(f"train.yaml:{HARDEN_BLOCK}.guard_set '{cfg.guard_set}' is trained on (pool, mix_with "
                             "or dataset); give a set no round trains on, e.g. holdout")


def _log_guard(log: Callable[[str], None], k: int, gap: dict, outcome: str) -> None:
    log(f"round {k}: AP@0.7 on {gap['set']} (no round trains on it) fell by {-100 * gap['gap']:.1f} points, "
        f"95 % interval [{100 * gap['low']:+.1f}, {100 * gap['high']:+.1f}]: {outcome}")


def _averaged_round(fusion: str, row: dict, current: Path, current_round: int, weights: Path, cfg: HardenConfig,
                    stage_cfg: PointStageFitConfig | None, out: Path, k: int, executor,
                    log: Callable[[str], None]) -> Path:
    """The guard's cure for a round it would not keep: ``round-k/averaged.pt``, the round's weights
    averaged with the ones it started from (``cfg.guard_average`` of the round's), with a point
    stage fitted to them (``stage_cfg``; None: none), evaluated and guarded in their turn. ``row``
    is updated to the averaged weights; what the round trained stays under its "unaveraged" key.
    Returns the averaged weights' file."""
    from ..perception.weights_io import average_weights

    averaged = out / f"round-{k}" / AVERAGED_WEIGHTS
    if not averaged.is_file():
        average_weights(current, weights, cfg.guard_average, averaged)
    row["unaveraged"] = {"weights": row["weights"], "evaluation": row["evaluation"], "guard": row["guard"],
                         **({"stage": row["stage"]} if "stage" in row else {})}
    if stage_cfg:
        row["stage"] = stage_of_round(fusion, averaged, out / f"round-{k}", stage_cfg, log)
    log(f"round {k}: evaluating {averaged} ({cfg.guard_average:g} of the round's weights) ...")
    row["weights"] = str(averaged.relative_to(out))
    row["evaluation"] = evaluate_round(fusion, averaged, cfg, _eval_cache(out, k, averaged), executor, log)
    row["guard"] = guard(_eval_cache(out, current_round, current), _eval_cache(out, k, averaged), cfg.guard_set) | {
        "averaged": cfg.guard_average}
    return averaged


def _eval_cache(out: Path, k: int, weights: Path) -> Path:
    """Where round ``k``'s evaluations are cached: the round's folder (``eval``, or ``eval-averaged``
    for its averaged weights), but for round 0 (the start weights) a folder of the data root named by
    the weights' digest, and their own point stage's when one is beside them (a round's weights
    given as the start: asg.evaluation.start_evaluations_dir), shared by every run (and control)
    that starts from the same model with the same code."""
    from ..evaluation import start_evaluations_dir
    from ..generator.run import file_digest
    from ..perception.weights_io import stage_path_of

    if k:
        return out / f"round-{k}" / ("eval" if weights.name != AVERAGED_WEIGHTS else f"eval-{Path(AVERAGED_WEIGHTS).stem}")
    stage = stage_path_of(weights)
    return start_evaluations_dir(file_digest(weights)[:16] + (f"-{file_digest(stage)[:8]}" if stage.is_file() else ""))


def is_kept(row: dict) -> bool:
    """Whether a card's round keeps its weights (every round before the guard existed did)."""
    return bool(row.get("weights")) and row.get("guard", {}).get("kept", True)


def guard(before_cache: Path, after_cache: Path, guard_set: str) -> dict:
    """{"set", "threshold", "gap", "low", "high", "frames", "kept"}: the AP@0.7 gap on ``guard_set``
    of a round's weights over the weights it started from (their evaluations' cached matches),
    paired bootstrap; kept unless the whole 95 % interval is below zero (``ApGap.not_worse``)."""
    from ..objective.paired import load_matches, paired_ap_gap

    gap = paired_ap_gap(load_matches(before_cache / f"{guard_set}.matches.npz"),
                        load_matches(after_cache / f"{guard_set}.matches.npz"), 0.7)
    return gap.guard_record(guard_set)


def _log_start_lidar(start: Path, log: Callable[[str], None]) -> None:
    """One line when the start weights' card says they were trained for another LiDAR than the one
    every round attacks, trains and evaluates with (the shipped preset)."""
    trained_for = lidar_of_weights(start)
    if trained_for not in (None, DEFAULT_LIDAR):
        log(f"{start}: trained for the {trained_for!r} LiDAR; every round casts its frames with {DEFAULT_LIDAR!r}, "
            "so round 0 scores them on another sensor and the rounds tune them to it")


def _start_weights(weights: Path | None, fusion: str, name: str) -> Path:
    """The weights file to start from: ``weights`` (a .pt, or a harden card: its last kept round's) or
    the shipped ``name``; InputError if missing or not loadable by ``fusion``'s detector."""
    from ..perception import check_weights_file

    if weights is None:
        return weights_path(name)
    path = Path(weights)
    if path.suffix == ".json" and path.is_file():
        try:
            card = json.loads(path.read_text())
            card["rounds"][0]  # a card with a finished round
            kept = [r for r in card["rounds"] if is_kept(r)]
            path = path.parent / kept[-1]["weights"] if kept else Path(card["start"]["weights"])
        except (ValueError, KeyError, IndexError, TypeError, AttributeError):
            raise InputError(f"--weights {weights}: not a harden card (card.json) with a finished round") from None
    if not path.is_file():
        raise InputError(f"--weights {path}: no such file; give a .pt written by asg train, finetune or harden")
    check_weights_file(fusion, path)  # one clear line for a corrupt or foreign file
    return path


def _pool(cfg: HardenConfig) -> list[Scene]:
    """Every train-split scene of the pool sets, in a seeded order (the rounds' slices)."""
    from ..datasets import build_dataset, dataset_path, iter_frames

    scenes: list[Scene] = []
    seen: dict[str, int] = {}
    for name in cfg.pool:
        if not (dataset_path(name) / "index.json").is_file():
            build_dataset(name)
        for scene in iter_frames(name, "train"):
            # ids repeat across a set's logs (the same town, seed and time at two densities) and
            # across sets: a repeat gets a suffix, so that each scene has its own folder
            seen[scene.scene_id] = seen.get(scene.scene_id, 0) + 1
            if seen[scene.scene_id] > 1:
                scene = Scene.from_dict(scene.to_dict() | {"scene_id": f"{scene.scene_id}_{seen[scene.scene_id]}"})
            scenes.append(scene)
    order = np.random.default_rng([cfg.seed, 7]).permutation(len(scenes))
    return [scenes[int(i)] for i in order]


def _round_scenes(fusion: str, weights: Path, scenes: list[Scene], cfg: HardenConfig, space, round_dir: Path,
                  executor, detector_factory: str | None, log: Callable[[str], None]) -> dict:
    """Make (or find) the round's training scenes, ``round_dir/scenes/``, and return the record of
    how they were made (``round_dir/data.json``). A round whose scenes and record are both on disk
    does not make them again: a run folder copied to another machine (say, a committed one without
    its attack folder) resumes at its training."""
    folder, record = round_dir / "scenes", round_dir / "data.json"
    if (folder / ".complete").is_file() and record.is_file():
        return json.loads(record.read_text())
    made, data = round_data(fusion, weights, scenes, cfg, space, round_dir / "attack", executor, detector_factory, log)
    save_scenes(made, folder)
    write_text_atomic(record, json.dumps(data, indent=1))
    return data
