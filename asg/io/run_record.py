"""The settings record of a run folder (``OUT/run.json``) and claiming a folder for a run.

Every command that writes a resumable run folder (``asg generate`` and everything built on the
generator, ``asg finetune``, ``asg harden``) claims it here: a folder whose record holds other
settings is refused in one line (``force`` empties it first); a rerun with the same settings resumes.
So do the commands that write a folder of scene files (``asg scenes extract``, ``asg scenes import``):
:func:`check_scene_folder` before they read their source, :func:`claim_scene_folder` before the
first scene is written; and ``asg simulate``'s traffic log: :func:`check_log_folder` before it
simulates, :func:`claim_log_folder` once the log is written.
"""
from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Callable, Iterable

from sumo_scenarios.atomic import write_text_atomic
from sumo_scenarios.checks import output_dir
from sumo_scenarios.errors import InputError
from sumo_scenarios.log import FCD_NAME, LOG_FILES, META_NAME

from ..schemas import SchemaFile, schema_of, stamped, unversioned

#: the file in a run folder that records its settings
RUN_RECORD = "run.json"


def claim(out: Path, settings: dict, force: bool = False, *, what: str = "a run",
          contents: Iterable[str] | None = None, holds_results: Callable[[Path], bool] | None = None,
          as_today: Callable[[dict], dict] = lambda record: record) -> dict:
    """Make ``out`` the folder of a run with ``settings`` and record them; returns them as recorded
    (JSON: tuples become lists).

    Refused (InputError) if ``out`` records other settings while ``holds_results(out)`` (default:
    whenever it has a record), or holds results and no record. ``force`` removes ``contents`` (names
    in ``out``; None: the whole folder) first. ``as_today`` fills in a record written before a
    setting existed (its default)."""
    out = Path(out)
    settings = json.loads(json.dumps(settings))
    if force and out.is_dir():
        for name in ([None] if contents is None else contents):
            p = out if name is None else out / name
            shutil.rmtree(p) if p.is_dir() else p.unlink(missing_ok=True)
    output_dir(out)
    check_claim(out, settings, what=what, holds_results=holds_results, as_today=as_today)
    record = out / RUN_RECORD
    try:
        write_text_atomic(record, json.dumps(stamped(SchemaFile.RUN, settings), indent=1, sort_keys=True))
    except OSError as exc:
        raise InputError(f"--out {out}: cannot write in it ({exc.strerror}); give a writable folder") from None
    return settings


def check_claim(out: Path, settings: dict, *, what: str = "a run", holds_results: Callable[[Path], bool] | None = None,
                as_today: Callable[[dict], dict] = lambda record: record) -> None:
    """What :func:`claim` refuses (without ``force``), refused without writing anything."""
    out = Path(out)
    holds_results = holds_results or (lambda folder: (folder / RUN_RECORD).is_file())
    if not out.is_dir():
        return
    record = out / RUN_RECORD
    if record.is_file() and holds_results(out):
        old = read_record(record)
        schema_of(SchemaFile.RUN, old, str(record))  # one from a newer asg is refused, not compared
        diff = first_difference(as_today(unversioned(old)), json.loads(json.dumps(settings)))
        if diff:
            raise InputError(f"{out} holds {what} made with other settings ({diff}); give another --out, "
                             f"or --force to start it over")
    elif not record.is_file() and holds_results(out):
        raise InputError(f"{out} holds {what} that recorded no settings; give another --out, or --force")


def _holds_scenes(folder: Path) -> bool:
    return (folder / RUN_RECORD).is_file() or any(folder.glob("*.yaml"))


def check_scene_folder(out: Path, settings: dict, force: bool) -> None:
    """Refuse (InputError) a folder of scene files written with other settings, or with none recorded
    (``force``: nothing is refused, :func:`claim_scene_folder` empties it); writes nothing."""
    if not force:
        check_claim(out, settings, what="scene files", holds_results=_holds_scenes)


def claim_scene_folder(out: Path, settings: dict, force: bool) -> None:
    """Make ``out`` a folder of scene files written with ``settings`` (its ``run.json``); ``force``
    removes its scene files (``*.yaml``) and record first. The same settings again: the same files
    are written again (an interrupted run completes)."""
    out = Path(out)
    contents = [RUN_RECORD, *(p.name for p in out.glob("*.yaml"))] if out.is_dir() else []
    claim(out, settings, force, what="scene files", contents=contents, holds_results=_holds_scenes)


def _holds_log(folder: Path) -> bool:
    return (folder / RUN_RECORD).is_file() or (folder / FCD_NAME).is_file() or (folder / META_NAME).is_file()


def check_log_folder(out: Path, settings: dict, force: bool) -> None:
    """Refuse (InputError) a folder holding a traffic log simulated with other settings, or with
    none recorded (``force``: nothing is refused); writes nothing."""
    if not force:
        check_claim(out, settings, what="a traffic log", holds_results=_holds_log)


def claim_log_folder(out: Path, settings: dict, force: bool = False) -> None:
    """Record ``settings`` as those of the traffic log in ``out`` (checked before it was simulated:
    only a record of other settings is refused now); ``force`` first removes the files a log folder
    holds (sumo_scenarios.log.LOG_FILES) and its record, nothing else."""
    claim(out, settings, force, what="a traffic log", contents=[RUN_RECORD, *LOG_FILES])


def with_defaults(record: dict, defaults: dict) -> dict:
    """``record`` with every setting it lacks (nested mappings walked) taken from ``defaults``: a
    setting added after a record was written has a default that reproduces the earlier behaviour,
    so a folder written before it resumes instead of being refused as made with other settings."""
    def fill(old, default):
        if isinstance(old, dict) and isinstance(default, dict):
            return {**{k: v for k, v in default.items() if k not in old},
                    **{k: fill(v, default.get(k)) for k, v in old.items()}}
        return old

    return fill(record, json.loads(json.dumps(defaults)))


def first_difference(a, b, where: str = "") -> str | None:
    """The first setting that differs between two records, as 'key: old -> new' (None if equal)."""
    if isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b)):
            d = first_difference(a.get(k), b.get(k), f"{where}.{k}" if where else k)
            if d:
                return d
        return None
    return None if a == b else f"{where}: {a!r} -> {b!r}"


def read_record(path: Path) -> dict:
    """A run folder's record; InputError if it is unreadable or not a mapping."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        raise InputError(f"{path} is unreadable; give another --out, or --force to start it over") from None
    if not isinstance(data, dict):
        raise InputError(f"{path} is not a run record; give another --out, or --force to start it over")
    return data
