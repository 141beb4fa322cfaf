"""``asg export SOURCE --format opv2v|kitti|openscenario|sumo --out DIR``: scenes other tools read.

SOURCE is an ``asg generate`` run folder (its final scenes), a data set (a name such as
``challenging-attfuse-val`` or a folder with index.json) or a folder of scene yaml. Every scene is
rendered with the v2xp LiDAR (what the detectors saw) where the format holds point clouds. File
names come from scene ids, which are checked safe on load; nothing is written outside DIR, and
each file is written atomically. Formats and their conventions: docs/export.md.
"""
from __future__ import annotations

from pathlib import Path
from typing import Callable, Iterator

from sumo_scenarios.errors import InputError

from ...scene import Scene, load_scene

#: each export format (``asg export --format``) and its writer (module of this package, class)
WRITERS = {"opv2v": ("opv2v", "ScenarioWriter"), "kitti": ("kitti", "KittiWriter"),
           "openscenario": ("openscenario", "XoscWriter"), "sumo": ("sumo", "RoutesWriter")}
FORMATS = tuple(WRITERS)


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


def export(source: Path | str, fmt: str, out: Path, net: Path | None = None,
           progress: Callable[[int], None] | None = None) -> int:
    """Write every scene of ``source`` in format ``fmt`` under ``out``; returns the scene count."""
    if fmt not in FORMATS:
        raise InputError(f"unknown format '{fmt}'; choose one of {', '.join(FORMATS)}")
    from sumo_scenarios.checks import output_dir

    out = output_dir(Path(out))
    import importlib

    module, writer_class = WRITERS[fmt]
    writer = getattr(importlib.import_module(f".{module}", __package__), writer_class)(out, net)
    n = 0
    for n, scene in enumerate(unique_ids(source_scenes(source)), start=1):
        writer.write(scene)
        if progress:
            progress(n)
    writer.close()
    if n == 0:
        raise InputError(f"{source}: no scenes to export")
    return n


def net_of(scene: Scene, net: Path | None) -> Path:
    """The SUMO net a scene was taken from: ``net`` if given, else the bundled or imported town of
    that name."""
    if net is not None:
        if not Path(net).is_file():
            raise InputError(f"--net {net}: file not found")
        return Path(net)
    from sumo_scenarios.towns import resolve_net

    try:
        return resolve_net(town=scene.town)[1]  # a name, never a path out of the towns' folders
    except InputError:
        raise InputError(f"scene {scene.scene_id} comes from '{scene.town}', which is not a bundled or imported town; "
                         "give its SUMO net with --net PATH") from None
