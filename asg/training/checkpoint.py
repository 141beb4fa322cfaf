"""Training checkpoints: the resumable state of an unfinished chunk (``runs/train/NAME/last.pt``):
model, optimiser, scheduler, step, generator states and the earlier chunks, as plain tensors,
numbers and strings (loaded with ``weights_only=True``, never unpickling objects)."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch

from sumo_scenarios.atomic import atomic_path
from sumo_scenarios.errors import InputError


def load_checkpoint(path: Path) -> dict | None:
    """The resumable state of an unfinished chunk (None if there is none); tensors only, never
    unpickled objects. A damaged file is one InputError saying how to start the chunk over."""
    if not path.is_file():
        return None
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises several types for damaged files
        raise InputError(f"{path}: the training checkpoint is damaged ({type(exc).__name__}); "
                         f"delete it to start this chunk over") from None
    needed = {"model", "optimizer", "scheduler", "step", "wall_s", "rng", "torch_rng", "previous"}
    if not isinstance(state, dict) or not needed <= set(state):
        raise InputError(f"{path}: not a training checkpoint of this version; delete it to start this chunk over")
    return state


def save_checkpoint(path: Path, model, opt, sched, step: int, wall_s: float, rng: np.random.Generator,
                previous: dict) -> None:
    state = {"model": model.state_dict(), "optimizer": opt.state_dict(), "scheduler": sched.state_dict(),
             "step": step, "wall_s": wall_s, "rng": json.dumps(rng.bit_generator.state),
             "torch_rng": torch.get_rng_state(), "previous": json.dumps(previous)}
    with atomic_path(path) as tmp:
        torch.save(state, tmp)


def started_from(state: dict) -> str | None:
    """The weights file (e.g. ``single.pt``) the unfinished chunk started from with ``--init-from``
    (the first chunk of a new sequence), or None for a chunk that continues its model's own
    weights (whose sequence may itself have started so)."""
    previous = json.loads(state.get("previous", "{}"))
    return None if previous.get("chunks") else previous.get("init_from", {}).get("weights")
