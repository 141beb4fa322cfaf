"""``asg export SOURCE --format FORMAT --out DIR``: scenes other tools read (a format: a module here).

SOURCE is an ``asg generate`` run folder (its final scenes), a data set (a name such as
``challenging-attfuse-val`` or a folder with index.json) or a folder of scene yaml. Every scene is
rendered with the v2xp LiDAR (what the detectors saw) where the format holds point clouds. File
names come from scene ids, which are checked safe on load; nothing is written outside DIR, and
each file is written atomically. Formats and their conventions: docs/export.md.

``--views all`` writes each scene once more as each collaborator sees it (that agent the ego, the
others its collaborators; scene id ``SCENE-as-AGENT``): a training set for a tool that trains on its
ego's view only (OpenCOOD's trainer), as asg's own training does with ``views: all``.
"""
from __future__ import annotations

from enum import Enum
from pathlib import Path
from typing import Callable, Iterator

from sumo_scenarios.errors import InputError

from ...registry import import_modules
from ...scene import Scene, load_scene
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


def unique_ids(scenes: Iterator[Scene]) -> Iterator[Scene]:
    """The scenes, a repeated id made unique by its repeat number (``ID-2``, ``ID-3``): a data set may
    hold two scenes of one id (the same town, seed and time at two traffic densities), which would
    otherwise be written into one folder or file."""
    from dataclasses import replace

    seen: dict[str, int] = {}
    for scene in scenes:
        k = seen[scene.scene_id] = seen.get(scene.scene_id, 0) + 1
        yield scene if k == 1 else replace(scene, scene_id=f"{scene.scene_id}-{k}")


class Views(str, Enum):
    """Which views of a scene an export writes: its ego's, or every sensing agent's in turn."""

    EGO = "ego"
    ALL = "all"


def every_view(scenes: Iterator[Scene]) -> Iterator[Scene]:
    """Each scene as it is, then as each collaborator sees it: that agent the ego, the ego and the
    other collaborators its collaborators, id ``SCENE-as-AGENT``. A scene whose links were degraded
    (``link``: what each collaborator's message went through on its way to the ego) is refused:
    those records are the ego's and do not hold for another receiver."""
    from dataclasses import replace

    for scene in scenes:
        yield scene
        if scene.link:
            raise InputError(f"{scene.scene_id}: its collaborators' links were degraded on the way to its ego; "
                             "export it with --views ego")
        for agent_id in scene.collaborators:
            others = tuple(a for a in scene.sensing_ids if a != agent_id)
            yield replace(scene, scene_id=f"{scene.scene_id}-as-{agent_id}", ego_id=agent_id, collaborators=others)


def export(source: Path | str, fmt: str, out: Path, net: Path | None = None,
           progress: Callable[[int], None] | None = None, views: Views = Views.EGO) -> int:
    """Write every scene of ``source`` in format ``fmt`` under ``out`` (with ``views`` ALL, each
    scene as each of its sensing agents sees it: :func:`every_view`); returns the scene count."""
    writer_class = EXPORT_FORMATS.entry(fmt)
    from sumo_scenarios.checks import output_dir

    writer = writer_class(output_dir(Path(out)), net)
    scenes = unique_ids(source_scenes(source))
    n = 0
    for n, scene in enumerate(every_view(scenes) if views is Views.ALL else scenes, start=1):
        writer.write(scene)
        if progress:
            progress(n)
    writer.close()
    if n == 0:
        raise InputError(f"{source}: no scenes to export")
    return n
