"""Model cards: ``WEIGHTS.json`` beside each weights file, recording the chunks that trained it,
what they trained on, and its validation AP (written atomically, read back as plain JSON)."""
from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Callable

from sumo_scenarios.atomic import write_text_atomic
from sumo_scenarios.errors import InputError

from ..io.json_file import read_json
from ..perception.fusion import card_settings_of, fusions_of, weights_names
from ..perception.weights_io import WEIGHTS_DIR
from ..sensors.lidar_spec import DEFAULT_LIDAR


def write_card(name: str, weights_dir: Path, cfg, chunks: list[dict], previous: dict, threads: int, *,
                dataset: str, examples: int, batch_size: int, branch_fit: dict | None = None) -> None:
    """The model card of ``name``: the chunks that made it (whole-network ones count as detector
    steps), their total wall time and, when the last step was a branch fit, that fit."""
    card = {"weights": f"{name}.pt", "fusion": fusions_of(name),
            "dataset": dataset, "examples": examples,
            # detector steps: the chunks that trained the whole network (branch chunks and fits are listed apart)
            "steps": sum(c["steps"] for c in chunks if c.get("part", "all") == "all"),
            "batch_size": batch_size, "train_wall_s": round(sum(c["wall_s"] for c in chunks), 1),
            "chunks": chunks, "threads": threads,
            # how the shipped IoU and refinement branches were made: a fit on the frozen detector,
            # absent when the last chunk trained them alongside the whole network
            **({"branch_fit": branch_fit} if branch_fit else {}),
            **({"init_from": previous["init_from"]} if previous.get("init_from") else {}),
            # the point stage fitted to earlier weights stays in use (asg train --point-stage refits it)
            **({"point_stage": previous["point_stage"]} if previous.get("point_stage") else {}),
            "lidar": trained_lidar(chunks),
            **card_settings_of(name, cfg)}
    write_text_atomic(weights_dir / f"{name}.json", json.dumps(card, indent=1))


def trained_lidar(chunks: list[dict]) -> str:
    """The LiDAR preset the last whole-network chunk of ``chunks`` rendered its frames with (a chunk
    records it when it is not the shipped one)."""
    whole = [c for c in chunks if c.get("part", "all") == "all"]
    return whole[-1].get("lidar", DEFAULT_LIDAR) if whole else DEFAULT_LIDAR


def lidar_of_weights(weights: Path) -> str | None:
    """The LiDAR preset the model card beside ``weights`` (NAME.json next to NAME.pt, as asg train
    writes it) records them trained for; None without a readable card (a missing one, or a pipe
    or a device beside a user's weights, is never read: asg.io.json_file; a link is followed)."""
    try:
        card = read_json(Path(weights).with_suffix(".json").resolve(), "the model card")
    except InputError:
        return None
    lidar = card.get("lidar") if isinstance(card, dict) else None
    return lidar if isinstance(lidar, str) else None


def card_validation(name: str, log: Callable[[str], None] = print, set_name: str = "normal-val",
                    *, weights_dir: Path) -> dict:
    """Evaluate the ``name`` weights in ``weights_dir`` (a training run folder) on ``set_name``
    (every fusion that uses them) and record the APs in that folder's model card."""
    from ..evaluation import evaluate
    from ..perception.targets import resolve_target

    card_path = weights_dir / f"{name}.json"
    card = json.loads(card_path.read_text()) if card_path.is_file() else {"weights": f"{name}.pt"}
    card["validation"] = {}
    for fusion in fusions_of(name):  # none and late share 'single'
        t0 = time.perf_counter()
        res = evaluate(resolve_target(fusion), set_name, weights_file=str(weights_dir / f"{name}.pt"))
        card["validation"][fusion] = {"set": set_name, "frames": res["frames"],
                                      "ap": {k: round(v, 4) for k, v in res["ap"].items()},
                                      "eval_wall_s": round(time.perf_counter() - t0, 1)}
        log(f"{fusion} on {set_name}: AP {res['ap']}")
    write_text_atomic(card_path, json.dumps(card, indent=1))
    return card


def previous_training(name: str, weights_dir: Path = WEIGHTS_DIR) -> dict:
    """What the weights of ``name`` in ``weights_dir`` were trained with (from its card), or {} if
    none: a new run then continues from them (training in chunks across sittings)."""
    card_path = weights_dir / f"{name}.json"
    if not (weights_dir / f"{name}.pt").is_file() or not card_path.is_file():
        return {}
    card = json.loads(card_path.read_text())
    chunks = card.get("chunks") or [{"steps": card.get("steps", 0), "lr": card.get("lr"), "seed": card.get("seed"),
                                     "wall_s": card.get("train_wall_s", 0.0)}]
    out = {"chunks": chunks, "steps_total": sum(c.get("steps", 0) for c in chunks),
           # what the detector chunks trained on, for a branch fit's card
           **{k: card[k] for k in ("dataset", "examples", "batch_size", "point_stage") if k in card}}
    if card.get("init_from"):
        out["init_from"] = card["init_from"]
    return out


def init_record(init_from: str, weights_dir: Path) -> dict:
    """What a new sequence starts from: the weights name, their steps and training time (from
    their card), recorded in the new model card."""
    names = weights_names()
    if init_from not in names:
        raise InputError(f"unknown weights '{init_from}' for --init-from; choose one of {', '.join(names)}")
    if not (weights_dir / f"{init_from}.pt").is_file():
        raise InputError(f"{weights_dir / f'{init_from}.pt'}: weights not found; train them first with 'asg train'")
    card_path = weights_dir / f"{init_from}.json"
    card = json.loads(card_path.read_text()) if card_path.is_file() else {}
    return {"weights": f"{init_from}.pt", "steps": card.get("steps", 0), "train_wall_s": card.get("train_wall_s", 0.0)}
