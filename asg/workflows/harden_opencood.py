"""``asg harden --fusion opencood:DIR``: one round of hardening an OpenCOOD model with OpenCOOD's own
trainer on scenes asg made against it, scored before and after with paired intervals.

1. The round's scenes (``--data``): ``adversarial``, the normal train split attacked against the
   model by the paper's protocol (its challenging set, ``challenging-opencood-NAME-DIGEST-train``,
   built or resumed); ``random``, one plausible random perturbation of each of the same scenes (the
   control at equal compute); ``normal``, the scenes unperturbed.
2. ``OUT/train``: those scenes and the normal train split beside them (against forgetting), in the
   OPV2V layout OpenCOOD reads (``asg export --format opv2v``), the two kinds' folders prefixed
   ``round-`` and ``normal-``; ``OUT/val``: normal-val likewise (the trainer's validation loss).
3. ``OUT/model``: DIR's config and checkpoint, trained ``opencood_epochs`` more epochs by OpenCOOD's
   ``tools/train.py`` (asg.perception.opencood.trainer; resumable, it saves every epoch).
4. Before (DIR) and after (``OUT/model``) on the config's evaluation sets, the model's own
   challenging val set and the guard set: AP by both yardsticks and the AP@0.7 gap with its 95 %
   paired-bootstrap interval; then the paper's protocol on normal-val against the new model.

Every step resumes: the scenes and exports are written whole or not at all, the trainer resumes from
its last epoch, the new model's evaluations are cached in ``OUT/eval`` and the starting model's in
the data root (:func:`start_cache`, shared by a run and its controls). ``OUT/card.json`` holds the result.
"""
from __future__ import annotations

import json
from dataclasses import asdict, replace
from pathlib import Path
from typing import Callable

from sumo_scenarios.atomic import atomic_dir, write_text_atomic
from sumo_scenarios.errors import InputError

from ..objective.ap import Yardstick
from ..objective.paired import ApGap, load_matches, paired_ap_gap, save_matches
from ..objective.pooled import FINETUNE_PAIR, REATTACK_PAIR, PooledAP, pair_json, pooled_pair
from ..perception.targets import resolve_target

#: the normal sets a round trains beside and validates on
TRAIN_SPLIT, VAL_SET = "normal", "normal-val"
#: the AP threshold of the reported gaps (the paper's headline)
GAP_THRESHOLD = 0.7


def harden_opencood(fusion: str, out: Path, cfg, executor=None, force: bool = False,
                    detector_factory: str | None = None, log: Callable[[str], None] = print) -> dict:
    """One round of hardening the OpenCOOD model ``fusion`` (``opencood:DIR``) into ``out`` with the
    harden settings ``cfg`` (its ``data``, ``opencood_epochs``, ``eval_sets``, ``guard_set``,
    ``reattack``); returns the card."""
    from ..generator.run import file_digest
    from ..io.run_record import claim
    target = resolve_target(fusion).check().check_trainable()
    start = target.model_dir
    files = target.model_files()
    settings = {"fusion": fusion, "start": {k: file_digest(p) for k, p in files.items()}, "data": cfg.data,
                "epochs": cfg.opencood_epochs, "eval_sets": list(cfg.eval_sets), "guard_set": cfg.guard_set,
                "reattack": cfg.reattack, "detector": detector_factory}
    claim(out, settings, force, what="a hardening run")
    scenes = round_scenes(fusion, cfg.data, executor, detector_factory, log)
    _export(out / "train", {"round": scenes, "normal": _normal_scenes()}, log)
    _export(out / "val", {"": list(_scenes_of(VAL_SET))}, log)
    model = out / "model"
    from ..perception.opencood.trainer import run_trainer, seed_from

    seed_from(model, start, out / "train", out / "val", cfg.opencood_epochs)
    log(f"training {model} with OpenCOOD's trainer ({cfg.opencood_epochs} epochs; its log: {model / 'train.log'}) ...")
    run_trainer(model)
    after = target.name_of(model)
    card = {"fusion": fusion, "data": cfg.data, "scenes": len(scenes), "model": str(model),
            "epochs": cfg.opencood_epochs, "config": asdict(cfg),
            "evaluation": evaluate_pair(fusion, after, cfg, out / "eval", executor, detector_factory, log)}
    if cfg.guard_set:
        gap = card["evaluation"][cfg.guard_set]["gap"][Yardstick.GLOBAL.value]
        card["guard"] = ApGap.from_dict(gap).guard_record(cfg.guard_set)
        if not card["guard"]["kept"]:
            log(f"AP@0.7 on {cfg.guard_set} (never trained on) fell by {-100 * gap['gap']:.1f} points, 95 % interval "
                f"[{100 * gap['low']:+.1f}, {100 * gap['high']:+.1f}]: keep {start}, not {model}")
    write_text_atomic(out / "card.json", json.dumps(card, indent=1))
    if cfg.reattack:
        card["reattack"] = reattack_pair(fusion, after, executor, detector_factory, log)
        write_text_atomic(out / "card.json", json.dumps(card, indent=1))
    return card


def round_scenes(fusion: str, data: str, executor, detector_factory: str | None, log: Callable[[str], None]) -> list:
    """The round's training scenes of kind ``data`` (module docstring, step 1)."""
    normal = _normal_scenes()
    if data == "normal":
        return normal
    if data == "random":
        from ..generator.config import load_generate_config
        from .random_control import ATTACK_SEED, random_draw

        gen_cfg = load_generate_config(fusion=fusion)
        return [random_draw(s, gen_cfg, ATTACK_SEED) for s in normal]
    from .challenging import build_challenging

    log(f"attacking normal's train split against {fusion} (or resuming) ...")
    built = build_challenging(fusion, "train", executor, detector_factory=detector_factory, log=log)
    from ..datasets import iter_frames

    return list(iter_frames(built))


def _normal_scenes() -> list:
    from ..datasets import iter_frames

    return list(iter_frames(TRAIN_SPLIT, "train"))


def _scenes_of(set_name: str):
    from ..datasets import scenes_of

    return scenes_of(set_name)


def _export(folder: Path, groups: dict[str, list], log: Callable[[str], None]) -> None:
    """``folder`` in the OPV2V layout: every scene of each group, its scenario folder prefixed with the
    group's name (``NAME-``); written whole (a stopped export is made again)."""
    if (folder / ".complete").is_file():
        return
    from ..io.export import EXPORT_FORMATS

    log(f"exporting {sum(map(len, groups.values()))} scenes to {folder} (OPV2V layout) ...")
    with atomic_dir(folder) as work:
        writer = EXPORT_FORMATS.entry("opv2v")(work, None)
        for prefix, scenes in groups.items():
            for scene in scenes:
                writer.write(replace(scene, scene_id=f"{prefix}-{scene.scene_id}" if prefix else scene.scene_id))
        writer.close()
        (work / ".complete").write_text("")


def evaluate_pair(before: str, after: str, cfg, cache: Path, executor, detector_factory: str | None,
                  log: Callable[[str], None]) -> dict:
    """{set: {"before", "after": pooled APs, "frames", "gap": {yardstick: the AP@0.7 gap after -
    before with its 95 % paired interval}}} on the config's evaluation sets, ``before``'s own
    challenging val set and the guard set; ``after``'s evaluations cached in ``cache``, ``before``'s
    in :func:`start_cache` (shared with the controls)."""
    from ..evaluation import evaluate
    from .challenging import build_challenging

    own_val = build_challenging(before, "val", executor, detector_factory=detector_factory, log=log).name
    sets = dict.fromkeys((*cfg.eval_sets, own_val, *([cfg.guard_set] if cfg.guard_set else [])))
    table, start = {}, start_cache(before)
    for set_name in sets:
        scored = {}
        for when, fusion in zip(FINETUNE_PAIR, (before, after)):
            folder, name = (start, set_name) if when == "before" else (cache, f"{when}-{set_name}")
            hit, matches = folder / f"{name}.json", folder / f"{name}.matches.npz"
            if not (hit.is_file() and matches.is_file()):
                result = evaluate(fusion, set_name, executor=executor, keep_matches=True)
                folder.mkdir(parents=True, exist_ok=True)
                save_matches(matches, result["matches"])
                write_text_atomic(hit, json.dumps(PooledAP.from_result(result).to_json(4) | {"frames": result["frames"]}))
            scored[when] = (json.loads(hit.read_text()), load_matches(matches))
        (b, b_matches), (a, a_matches) = scored["before"], scored["after"]
        row = pair_json({"before": PooledAP.from_json(b), "after": PooledAP.from_json(a)}) | {"frames": a["frames"]}
        row["gap"] = {y.value: paired_ap_gap(b_matches, a_matches, GAP_THRESHOLD, method=y).to_dict() for y in Yardstick}
        pair = pooled_pair(row, FINETUNE_PAIR)
        log(f"  {set_name}: AP@0.7 ours / per frame {pair['before'].text()} -> {pair['after'].text()}")
        table[set_name] = row
    return table


def start_cache(fusion: str) -> Path:
    """Where the evaluations of the round's starting model (``opencood:DIR``) are cached: a folder of
    the data root named by the digest of DIR's config and checkpoint (asg.evaluation.start_evaluations_dir),
    shared by every run and control that starts from it."""
    import hashlib

    from ..evaluation import start_evaluations_dir
    from ..generator.run import file_digest
    target = resolve_target(fusion)
    h = hashlib.sha256()
    for name, path in sorted(target.model_files().items()):
        h.update(name.encode() + b"\0" + file_digest(path).encode())
    return start_evaluations_dir(f"{target.kind}-{h.hexdigest()[:16]}")


def reattack_pair(before: str, after: str, executor, detector_factory: str | None, log: Callable[[str], None]) -> dict:
    """The paper's protocol on normal-val against ``after`` beside ``before``'s own attack:
    {"frames", "before", "after": each {"normal", "challenging"} pooled APs}."""
    from ..datasets import data_root
    from .challenging import build_challenging, set_name

    log(f"re-attacking {after} on normal-val ...")
    built = build_challenging(after, "val", executor, detector_factory=detector_factory, log=log)
    index = json.loads((built / "index.json").read_text())
    original = json.loads((data_root() / set_name(before, "val") / "index.json").read_text())
    return {"frames": index["frames"], "before": pair_json(pooled_pair(original, REATTACK_PAIR)),
            "after": pair_json(pooled_pair(index, REATTACK_PAIR))}


#: the harden block's settings a round of an OpenCOOD model reads; the others set asg's own trainer
OPENCOOD_SETTINGS = ("data", "opencood_epochs", "eval_sets", "guard_set", "reattack")


def check_opencood_settings(config: Path, given: dict, shipped: dict) -> None:
    """A ``--config`` whose harden block (``given``) changes, from train.yaml's (``shipped``), a
    setting an OpenCOOD round does not read (asg's trainer's steps, rate, mixing, augmentation, ...)
    is refused in one line: it would be ignored. Settings left as train.yaml has them pass."""
    ignored = sorted(k for k, v in given.items() if k not in OPENCOOD_SETTINGS and v != shipped.get(k))
    if ignored:
        raise InputError(f"{config}: {', '.join(ignored)} set asg's own trainer; a round of an OpenCOOD model reads "
                         f"only {', '.join(OPENCOOD_SETTINGS)} (OpenCOOD's trainer takes the rest from the folder's "
                         "config.yaml)")


def check_opencood_run(args) -> None:
    """What ``asg harden`` takes for an asg model and not for an OpenCOOD one, refused in one line."""
    if args.rounds != 1:
        raise InputError("--fusion opencood:DIR hardens one round at a time; give --rounds 1 (a further round: "
                         "--fusion opencood:OUT/model)")
    for flag, value in (("--weights", args.weights), ("--space", args.space)):
        if value is not None:
            raise InputError(f"{flag} applies to asg's own models; an OpenCOOD model starts from its folder's "
                             "checkpoint and is attacked with configs/generate.yaml's spaces")
