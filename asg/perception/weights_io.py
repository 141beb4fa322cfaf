"""Shipped weights: state_dicts loaded with ``weights_only=True`` (never unpickling objects)."""
from __future__ import annotations

from pathlib import Path

import torch
from torch import nn

from sumo_scenarios.errors import InputError

from .numerics import zero_subnormals_

WEIGHTS_DIR = Path(__file__).resolve().parent / "weights"


#: what to do when weights and model disagree (another fusion, another attfuse_fusion, another size)
_MISMATCH_HINT = ("; use the --fusion they were trained for (each names its settings file in "
                  "configs/detectors/, e.g. attfuse-wide's wide network) and the settings they were trained "
                  "with (e.g. attfuse_fusion), or retrain")


def user_weights_dir() -> Path:
    """Where a user's own trained weights are installed (``asg train --install``): the user's asg
    folder (``ASG_HOME``, else the platform's user data folder), ``weights/``."""
    from sumo_scenarios.paths import user_home

    return user_home() / "weights"


def weights_path(name: str) -> Path:
    """The weights file ``NAME.pt`` the detectors load: the user's installed one if there is one
    (:func:`user_weights_dir`), else the one shipped in the package."""
    user = user_weights_dir() / f"{name}.pt"
    return user if user.is_file() else WEIGHTS_DIR / f"{name}.pt"


#: the files of one set of weights: the weights, their model card, their point stage
def weights_files(folder: Path, name: str) -> list[Path]:
    return [folder / f"{name}.pt", folder / f"{name}.json", folder / f"{name}{STAGE_SUFFIX}"]


def seed_run_folder(run_dir: Path, *names: str) -> None:
    """Copy into the training run folder ``run_dir`` the weights it starts from (each of ``names``:
    the files of :func:`weights_files`, from where :func:`weights_path` finds them), unless it holds
    them already: training then reads and writes there, never in the package."""
    run_dir.mkdir(parents=True, exist_ok=True)
    for name in names:
        if not (run_dir / f"{name}.pt").is_file():
            _copy_weights(weights_path(name).parent, run_dir, name)


def install_weights(run_dir: Path, name: str) -> Path:
    """Install the weights ``name`` trained in ``run_dir`` (with their card and point stage) into
    :func:`user_weights_dir`, where every command then loads them; the installed weights file.
    The package's shipped files are never written."""
    if not (run_dir / f"{name}.pt").is_file():
        raise InputError(f"{run_dir / f'{name}.pt'}: no trained weights to install; run 'asg train' first")
    target = user_weights_dir()
    target.mkdir(parents=True, exist_ok=True)
    _copy_weights(run_dir, target, name)
    return target / f"{name}.pt"


def _copy_weights(source: Path, target: Path, name: str) -> None:
    """Copy the files of the weights ``name`` (:func:`weights_files`) that ``source`` holds into
    ``target``, each written atomically."""
    import shutil

    from sumo_scenarios.atomic import atomic_path

    for src, dst in zip(weights_files(source, name), weights_files(target, name)):
        if src.is_file():
            with atomic_path(dst) as tmp:
                shutil.copyfile(src, tmp)


#: the point stage's weights beside a detector's: NAME.pt -> NAME.stage.pt
STAGE_SUFFIX = ".stage.pt"
#: the stage a model without one of its own uses (trained on the single-agent detector's boxes)
DEFAULT_STAGE = "single"


def stage_path_of(weights_file: str | Path) -> Path:
    """Where the point stage of the weights ``weights_file`` (.../NAME.pt) is: .../NAME.stage.pt."""
    p = Path(weights_file)
    return p.with_name(p.name.removesuffix(".pt") + STAGE_SUFFIX)


def stage_file_for(weights_name: str, weights_file: str | Path | None = None) -> Path | None:
    """The point stage a detector uses: the one beside ``weights_file`` when given and present,
    else the shipped one of ``weights_name``, else the shipped single-agent one; None if none is."""
    candidates = ([stage_path_of(weights_file)] if weights_file else []) + [
        stage_path_of(weights_path(weights_name)), stage_path_of(weights_path(DEFAULT_STAGE))]
    return next((p for p in candidates if p.is_file()), None)


def load_state(model: nn.Module, path: str | Path, allow_missing: str | tuple[str, ...] | None = None) -> nn.Module:
    """Load a state_dict into ``model``; a missing, corrupt or mismatched file is one InputError.

    ``allow_missing``: a key prefix (e.g. "head.iou.") or a tuple of them whose tensors the file may
    lack; those keep the model's own initial values (training a part added after the weights were
    made).
    """
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: weights not found; train them with 'asg train' or reinstall the package")
    try:
        state = torch.load(p, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises several types for corrupt files
        raise InputError(f"{p}: not a readable weights file ({type(exc).__name__}); retrain or reinstall") from None
    if isinstance(state, dict) and "model" in state and isinstance(state["model"], dict):
        state = state["model"]
    if not isinstance(state, dict):
        raise InputError(f"{p}: not a state_dict; retrain or reinstall")
    own = model.state_dict()
    missing, unexpected = _diff(own, state)
    if allow_missing:
        kept = [k for k in missing if k.startswith(allow_missing)]
        missing = [k for k in missing if not k.startswith(allow_missing)]
        state = {**{k: own[k] for k in kept}, **state}
    if missing or unexpected:
        what = f"missing {missing[0]}" if missing else f"unexpected {unexpected[0]}"
        raise InputError(f"{p}: weights do not match this model ({what}){_MISMATCH_HINT}")
    broken = next((k for k, v in state.items() if isinstance(v, torch.Tensor) and v.is_floating_point()
                   and not bool(torch.isfinite(v).all())), None)
    if broken is not None:  # a diverged training run: detections from these would be noise
        raise InputError(f"{p}: weights hold NaN or infinite values ({broken}); retrain with a lower learning rate")
    try:
        model.load_state_dict(state)
    except RuntimeError as exc:
        first = str(exc).splitlines()[1].strip() if len(str(exc).splitlines()) > 1 else str(exc)
        raise InputError(f"{p}: weights do not match this model ({first}){_MISMATCH_HINT}") from None
    zero_subnormals_(model)  # the same outputs, computed at full speed (numerics.py)
    model.eval()
    return model


def _diff(expected: dict, got: dict) -> tuple[list[str], list[str]]:
    return sorted(set(expected) - set(got)), sorted(set(got) - set(expected))


def save_state(model: nn.Module, path: str | Path) -> None:
    from sumo_scenarios.atomic import atomic_path

    with atomic_path(path) as tmp:
        torch.save(model.state_dict(), tmp)


def average_weights(start: str | Path, trained: str | Path, share: float, out: str | Path) -> Path:
    """Write ``(1 - share) * start + share * trained`` (two weights files of one network: every
    floating tensor averaged, counters taken from ``trained``) to ``out``, atomically; InputError if
    the files do not hold the same tensors."""
    from sumo_scenarios.atomic import atomic_path

    s, t = (torch.load(p, map_location="cpu", weights_only=True) for p in (start, trained))
    mismatch = next((k for k in s.keys() | t.keys() if k not in s or k not in t or s[k].shape != t[k].shape), None)
    if mismatch is not None:
        raise InputError(f"{start} and {trained}: not weights of one network ({mismatch}); average weights of one model")
    mixed = {k: ((1.0 - share) * s[k] + share * t[k]).to(s[k].dtype) if s[k].is_floating_point() else t[k] for k in s}
    with atomic_path(out) as tmp:
        torch.save(mixed, tmp)
    return Path(out)
