"""``asg export SOURCE --format FORMAT --out DIR``: scenes other tools read (a format: a module here).

SOURCE is an ``asg generate`` run folder (its final scenes), a data set (a name such as
``challenging-attfuse-val`` or a folder with index.json) or a folder of scene yaml. Every scene is
rendered with the v2xp LiDAR (what the detectors saw) where the format holds point clouds. File
names come from scene ids, which are checked safe on load; nothing is written outside DIR, and
each file is written atomically. Formats and their conventions: docs/export.md.

``--views all`` writes each scene once more as each collaborator sees it (that agent the ego, the
others its collaborators; scene id ``SCENE-as-AGENT``): a training set for a tool that trains on its
ego's view only (OpenCOOD's trainer), as asg's own training does with ``views: all``.

DIR records what it holds (``asg-export.json``: the source, format, views and net); an export into a
DIR that holds another one is refused in one line, and the same command again redoes it (a stopped
export is finished so).
"""
from __future__ import annotations

import itertools
import json
import os
from pathlib import Path
from typing import Callable, Iterator

from sumo_scenarios.atomic import write_text_atomic
from sumo_scenarios.errors import InputError

from ...registry import import_modules
from ...scene import Scene, load_scene
from ...scene.views import Views, every_view
from .base import EXPORT_FORMATS, net_of  # noqa: F401  (this package's API)

import_modules(__name__, __path__)  # each format's module registers its writer in EXPORT_FORMATS


def source_scenes(source: Path | str) -> Iterator[Scene]:
    """The scenes of ``source``: a run folder's final scenes, a data set, or scene yaml files."""
    p = Path(source)
    if (p / "scenes").is_dir() and (p / "run.json").is_file():
        finals = sorted(p.glob("scenes/*/final.yaml"))
        if not finals:
            raise InputError(f"{p}: a run folder with no finished scene; run 'asg generate' into it first")
        root = p.resolve()
        for f in finals:  # asg writes no link into a run folder: one that leads out of it is not read
            if f.is_symlink() or f.parent.is_symlink() or not f.resolve().is_relative_to(root):
                raise InputError(f"{f}: a link, which asg never writes into a run folder; regenerate the scene")
        return (load_scene(f) for f in finals)
    from ...datasets import scenes_of

    return scenes_of(str(source))


#: the record of what an export folder holds (written once its format could start, before any scene)
RECORD = "asg-export.json"


def held_export(out: Path, settings: dict[str, str | None]) -> bool:
    """Does ``out`` already record these ``settings``? InputError (one line) if it records others."""
    path = out / RECORD
    if not path.is_file():
        return False
    try:
        held = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError):
        raise InputError(f"{path}: not a record asg wrote; give another --out") from None
    if not isinstance(held, dict):
        raise InputError(f"{path}: not a record asg wrote; give another --out")
    for key, value in settings.items():
        if held.get(key) != value:
            raise InputError(f"{out} holds an export of {key} {held.get(key)!r}, not {value!r}; "
                             "give another --out, or the same settings to redo it")
    return True


def export(source: Path | str, fmt: str, out: Path, net: Path | None = None,
           progress: Callable[[int], None] | None = None, views: Views = Views.EGO) -> int:
    """Write every scene of ``source`` in format ``fmt`` under ``out`` (with ``views`` ALL, each
    scene as each of its sensing agents sees it: :func:`every_view`); returns the scene count."""
    writer_class = EXPORT_FORMATS.entry(fmt)
    if net is not None and not writer_class.reads_net:
        readers = ", ".join(name for name in EXPORT_FORMATS.names() if EXPORT_FORMATS.entry(name).reads_net)
        raise InputError(f"--net applies to the formats that read the scenes' SUMO net ({readers}); {fmt} reads none: drop it")
    from sumo_scenarios.checks import output_dir

    from ...datasets import unique_ids

    out = output_dir(Path(out))
    _refuse_links_inside(out)
    scenes = unique_ids(source_scenes(source))  # a run folder's too
    if views is Views.ALL:
        scenes = every_view(scenes)
    first = next(scenes, None)  # the source read and its first scene checked before the folder is claimed
    if first is None:
        raise InputError(f"{source}: no scenes to export")
    settings = {"source": _source_name(source), "format": fmt, "views": views.value,
                "net": None if net is None else str(Path(net).resolve())}
    held = held_export(out, settings)
    writer = writer_class(out, net)  # a format whose library is missing stops here
    if not held:
        write_text_atomic(out / RECORD, json.dumps(settings, indent=1) + "\n")
    n = 0
    for n, scene in enumerate(itertools.chain([first], scenes), start=1):
        writer.write(scene)
        if progress:
            progress(n)
    writer.close()
    return n


def _refuse_links_inside(out: Path) -> None:
    """Refuse (one InputError) an output folder holding a symbolic link anywhere inside it: a writer
    that wrote into ``out/training/velodyne`` or ``out/SCENE/0`` would write through it, outside ``out``."""
    for folder, dirs, files in os.walk(out):
        for name in (*dirs, *files):
            path = Path(folder) / name
            if path.is_symlink():
                raise InputError(f"{path}: a symbolic link inside --out {out}; an export writes nothing through "
                                 "a link: remove it or choose another folder")


def _source_name(source: Path | str) -> str:
    """A folder's absolute path, or a data set's name as given (``normal-val``)."""
    p = Path(source)
    return str(p.resolve()) if p.exists() else str(source)
