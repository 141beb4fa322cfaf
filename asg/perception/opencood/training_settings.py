"""The settings OpenCOOD's trainer (``opencood/tools/train.py`` and its ``train_utils``) reads from a
model folder's config.yaml, checked before hours of work start on a folder that cannot train:
``train_params`` (batch size, epochs, evaluation and save frequencies), ``loss`` (a loss module of
OpenCOOD's and its arguments), ``optimizer`` (a torch optimiser by name, its rate and arguments) and
``lr_scheduler`` (OpenCOOD's step, multistep or exponential schedule). One InputError naming the key
and what it must be."""
from __future__ import annotations

import math
from pathlib import Path

from sumo_scenarios.errors import InputError

#: OpenCOOD's schedules (train_utils.setup_lr_schedular): name -> the keys it reads
SCHEDULES = {"step": ("step_size", "gamma"), "multistep": ("step_size", "gamma"), "exponential": ("gamma",)}
#: ranges of the trainer's numbers: a batch, epochs, frequencies (in epochs)
LIMITS = {"batch_size": (1, 256), "epoches": (1, 100_000), "eval_freq": (1, 100_000), "save_freq": (1, 100_000)}


def check_trainable(hypes: dict, path: Path) -> None:
    """Refuse (one InputError naming ``path`` and the key) a config OpenCOOD's trainer cannot run."""
    params = _block(hypes, "train_params", path)
    for key, (lo, hi) in LIMITS.items():
        _whole(params.get(key), f"train_params.{key}", lo, hi, path)
    _loss(_block(hypes, "loss", path), path)
    _optimizer(_block(hypes, "optimizer", path), path)
    _schedule(_block(hypes, "lr_scheduler", path), path)


def _block(hypes: dict, key: str, path: Path) -> dict:
    value = hypes.get(key)
    if not isinstance(value, dict):
        raise InputError(f"{path}: OpenCOOD's trainer reads '{key}', a mapping, which the config lacks; "
                         "copy it from OpenCOOD's hypes_yaml")
    return value


def _whole(value, key: str, lo: int, hi: int, path: Path) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
        raise InputError(f"{path}: {key} must be a whole number from {lo} to {hi}, got {str(value)[:40]!r}")
    return value


def _positive(value, key: str, hi: float, path: Path) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (math.isfinite(value) and 0 < value <= hi):
        raise InputError(f"{path}: {key} must be a number in (0, {hi:g}], got {str(value)[:40]!r}")
    return float(value)


def _name(value, key: str, path: Path) -> str:
    if not isinstance(value, str) or not value.isidentifier():
        raise InputError(f"{path}: {key} must be a name, got {str(value)[:40]!r}")
    return value


def _loss(loss: dict, path: Path) -> None:
    from .runtime import module

    name = _name(loss.get("core_method"), "loss.core_method", path)
    known = sorted(p.stem for p in Path(module("loss").__file__).parent.glob("*.py") if not p.stem.startswith("_"))
    if name not in known:
        raise InputError(f"{path}: loss.core_method {name!r} is not one of OpenCOOD's losses ({', '.join(known)})")
    if not isinstance(loss.get("args"), dict):
        raise InputError(f"{path}: loss.args must be a mapping (OpenCOOD's loss reads its weights there)")


def _optimizer(optimizer: dict, path: Path) -> None:
    import torch

    name = _name(optimizer.get("core_method"), "optimizer.core_method", path)
    cls = getattr(torch.optim, name, None)
    if not (isinstance(cls, type) and issubclass(cls, torch.optim.Optimizer)):
        raise InputError(f"{path}: optimizer.core_method {name!r} is not a torch optimiser (Adam, SGD, ...)")
    _positive(optimizer.get("lr"), "optimizer.lr", 10.0, path)
    args = optimizer.get("args", {})
    if not isinstance(args, dict) or not all(isinstance(k, str) and k.isidentifier() for k in args):
        raise InputError(f"{path}: optimizer.args must map the optimiser's argument names to values")
    for key, value in args.items():
        if isinstance(value, float) and not math.isfinite(value):
            raise InputError(f"{path}: optimizer.args.{key} is not finite")


def _schedule(schedule: dict, path: Path) -> None:
    name = schedule.get("core_method")
    if name not in SCHEDULES:
        raise InputError(f"{path}: lr_scheduler.core_method must be one of {', '.join(SCHEDULES)}, got {str(name)[:40]!r}")
    _positive(schedule.get("gamma"), "lr_scheduler.gamma", 1.0, path)
    if name == "step":
        _whole(schedule.get("step_size"), "lr_scheduler.step_size", 1, 100_000, path)
    elif name == "multistep":
        steps = schedule.get("step_size")
        if not isinstance(steps, list) or not steps:
            raise InputError(f"{path}: lr_scheduler.step_size of a multistep schedule must be a list of epochs")
        for s in steps:
            _whole(s, "lr_scheduler.step_size", 1, 100_000, path)
