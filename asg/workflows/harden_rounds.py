"""A hardening round's parts that do not depend on how it trains (asg.workflows.harden): the
round's data (the attack, or a control), its evaluation on the fixed sets with a cache, the
re-attack on normal-val and the start scored on the re-attacked scenes, and the round's saved
scenes. ``cfg`` is a :class:`asg.workflows.harden.HardenConfig` throughout."""
from __future__ import annotations

import json
import shutil
from dataclasses import replace
from pathlib import Path
from typing import Callable

from sumo_scenarios.atomic import write_text_atomic

from ..objective.pooled import REATTACK_PAIR, PooledAP, pair_json, pooled_pair
from ..scene import Scene, load_scene
from .random_control import ATTACK_SEED, random_draw
from .trainers import Model

#: the name of the noisy evaluation set in a card
NOISY_SET = "normal-val-noisy"
#: a round's re-attack record of the weights the round started from on the scenes attacked against
#: the round, and the cache of those two evaluations in the round's folder
STARTED_FROM = "started_from"
REATTACK_EVAL = "reattack-eval"


def round_data(model: Model, scenes: list[Scene], cfg, space, run_dir: Path, executor,
               detector_factory: str | None, log: Callable[[str], None]) -> tuple[list[Scene], dict]:
    """The round's training scenes (see ``cfg.data``), made against ``model``, and a record of how
    they were made."""
    from ..generator.run import open_run
    from ..generator.config import load_generate_config

    gen_cfg = load_generate_config(fusion=model.target.name, weights=model.weights_arg)
    if space:
        gen_cfg = replace(gen_cfg, space=replace(gen_cfg.space, kinds=tuple(space))).validate()
    if cfg.data == "normal":
        return list(scenes), {"kind": "normal", "scenes": len(scenes)}
    if cfg.data == "random":
        made = [random_draw(s, gen_cfg, ATTACK_SEED) for s in scenes]
        return made, {"kind": "random", "scenes": len(made), "moved": sum(m is not s for m, s in zip(made, scenes))}
    from ..generator.run_folder import aggregate_pooled
    from ..generator.stages import Stage

    log(f"attacking {len(scenes)} scenes against {model.path} ...")
    run = open_run(gen_cfg, run_dir, scenes=scenes, record={"harden": str(run_dir), "detector": detector_factory},
                   seed=ATTACK_SEED).run(detector_factory=detector_factory, executor=executor, artifacts=False)
    ids = [e["scene_id"] for e in run.summary["scenes"]]
    made = [load_scene(run_dir / "scenes" / i / "final.yaml") for i in ids]
    agg = run.summary["aggregate"]
    return made, {"kind": "adversarial", "scenes": len(made), "skipped": len(run.skipped),
                  **pair_json({"normal": aggregate_pooled(agg, Stage.NORMAL), "challenging": aggregate_pooled(agg, Stage.FINAL)})}


def evaluate_round(model: Model, own_val: str, cfg, cache: Path, executor,
                   log: Callable[[str], None]) -> dict:
    """{set: {"ap", "ap_per_frame": AP by threshold, ours and the paper's (a pooled AP,
    asg.objective.pooled), "frames": N}} of ``model`` on the fixed evaluation sets, ``own_val`` (the
    challenging val set of the run's target, built) and the guard set, each result cached in ``cache`` (a cached result without the paper's yardstick, from before
    it was recorded, is evaluated again), the guard set's per-frame matches beside it
    (``SET.matches.npz``, for the guard's paired interval)."""
    sets = {s: s for s in (*cfg.eval_sets, own_val, *([cfg.guard_set] if cfg.guard_set else []))}
    if cfg.noisy:
        sets[NOISY_SET] = str(noisy_val_set())
    return {label: evaluated_set(model, label, set_arg, cache, label == cfg.guard_set, executor, log)
            for label, set_arg in sets.items()}


def evaluated_set(model: Model, label: str, set_arg: str, cache: Path, guarded: bool,
                  executor, log: Callable[[str], None]) -> dict:
    """``model`` on one set (``{"ap", "ap_per_frame", "frames"}``), cached in ``cache`` as
    ``LABEL.json``; ``guarded``: its per-frame matches too (``LABEL.matches.npz``), a cached result
    without them evaluated again."""
    from ..evaluation import evaluate
    from ..objective.paired import save_matches

    hit, matches = cache / f"{label}.json", cache / f"{label}.matches.npz"
    if hit.is_file():
        cached = json.loads(hit.read_text())
        pooled = PooledAP.from_json(cached)
        if pooled.ap_per_frame is not None and (matches.is_file() or not guarded):
            return pooled.to_json() | {"frames": cached["frames"]}
    result = evaluate(model.target, set_arg, weights_file=model.weights_arg, executor=executor, keep_matches=guarded)
    pooled = PooledAP.from_result(result)
    row = pooled.to_json(4) | {"frames": result["frames"]}
    cache.mkdir(parents=True, exist_ok=True)
    if guarded:
        save_matches(matches, result["matches"])
    write_text_atomic(hit, json.dumps(row))
    log(f"  {label}: AP@0.7 ours / per frame {pooled.text()} ({result['frames']} frames)")
    return row


def upgraded_rounds(rounds: list[dict]) -> list[dict]:
    """A card's rounds with every pooled AP in today's form (``{"ap", "ap_per_frame"}``): cards
    written before it kept AP by threshold at the top and the paper's under "per_frame"."""
    out = []
    for row in rounds:
        row = dict(row)
        row["evaluation"] = {s: PooledAP.from_json(ev).to_json() | {"frames": ev["frames"]}
                             for s, ev in row.get("evaluation", {}).items()}
        if row.get("reattack"):
            kept = {k: v for k, v in row["reattack"].items() if k == STARTED_FROM}  # written in today's form
            row["reattack"] = {"frames": row["reattack"]["frames"],
                               **pair_json(pooled_pair(row["reattack"], REATTACK_PAIR)), **kept}
        out.append(row)
    return out


def noisy_val_set() -> Path:
    """normal-val under the standard noisy V2X setting (built once under the data root)."""
    from ..datasets import data_root
    from ..datasets import scenes_of
    from ..scene.noisy import write_noisy_set

    return write_noisy_set(scenes_of("normal-val"), data_root() / NOISY_SET, seed=ATTACK_SEED)


def reattack_round(model: Model | None, own_val: str, out: Path, executor, detector_factory: str | None,
                   log: Callable[[str], None], evaluation: dict) -> dict:
    """The paper's protocol on normal-val against ``model``: {"frames", "normal", "challenging"},
    each a pooled AP (``{"ap", "ap_per_frame"}``; the paper's yardstick None for a set built before
    it was recorded) (round 0 from other than the shipped weights: those weights attacked).
    None: the run's target as shipped, whose own attack is its challenging val set ``own_val``; its
    AP is taken from the round's ``evaluation`` (scored by today's code), not from the AP the set's
    index recorded when it was built (older meshes or detectors give another figure for the same
    scenes); its "normal" from the evaluation's normal-val when the round has one, else from the index."""
    from .challenging import build_challenging
    from ..datasets import data_root

    if model is None:
        index = json.loads((data_root() / own_val / "index.json").read_text())
        normal = (PooledAP.from_json(evaluation["normal-val"]) if "normal-val" in evaluation
                  else pooled_pair(index, REATTACK_PAIR)["normal"])
        return {"frames": evaluation[own_val]["frames"],
                **pair_json({"normal": normal, "challenging": PooledAP.from_json(evaluation[own_val])})}
    log(f"re-attacking {model.path} on normal-val ...")
    built = build_challenging(model.target, "val", executor=executor, weights_file=model.weights_arg, out=out,
                              detector_factory=detector_factory)
    index = json.loads((built / "index.json").read_text())
    return {"frames": index["frames"], **pair_json(pooled_pair(index, REATTACK_PAIR))}


def started_from_on_reattack(started_from: Model, attacked: Model, round_dir: Path, executor,
                             log: Callable[[str], None]) -> dict:
    """The model a round started from, scored on the scenes its re-attack found against the
    round's weights (``round_dir/reattack``): their pooled AP and frames, and "gap", the round's
    weights over them on those same scenes ({yardstick: AP@0.7 gap with its 95 % paired interval}).
    The re-attack's gain over the start's own attack is this gap plus how much easier these scenes
    are for the start than its own attack: a gap below zero means the new attack found scenes the
    round is worse on than its start (the round moved its start's weak spots rather than removed
    them). Both evaluations cached in ``round_dir/reattack-eval``."""
    from ..objective.ap import Yardstick
    from ..objective.paired import load_matches, paired_ap_gap

    scenes, cache = str(round_dir / "reattack"), round_dir / REATTACK_EVAL
    row = evaluated_set(started_from, "started-from", scenes, cache, True, executor, log)
    evaluated_set(attacked, "attacked", scenes, cache, True, executor, log)
    before, after = (load_matches(cache / f"{label}.matches.npz") for label in ("started-from", "attacked"))
    return row | {"gap": {y.value: paired_ap_gap(before, after, 0.7, method=y).to_dict() for y in Yardstick}}


def save_scenes(scenes: list[Scene], folder: Path) -> None:
    """The round's training scenes, one yaml each (kept: a resumed round trains on the same)."""
    from sumo_scenarios.atomic import atomic_dir
    from ..scene import save_scene

    if (folder / ".complete").is_file():
        return
    if folder.exists():
        shutil.rmtree(folder)
    with atomic_dir(folder) as work:
        for s in scenes:
            save_scene(s, work / f"{s.scene_id}.yaml")
        (work / ".complete").write_text("")


def load_scenes(folder: Path) -> list[Scene]:
    return [load_scene(p) for p in sorted(folder.glob("*.yaml"))]
