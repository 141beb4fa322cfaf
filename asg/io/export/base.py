"""What the export formats share: their registry (``asg export --format``) and the SUMO net of a scene.

A format is a writer class in a module of this package, registered under its name: constructed
with the output folder (and ``--net``), ``write(scene)`` once per scene, then ``close()``. A writer
module keeps its heavy imports (the LiDAR, torch) inside its methods, so that the registry fills
when the package is imported without loading them.
"""
from __future__ import annotations

from pathlib import Path
from typing import ClassVar, Protocol

from sumo_scenarios.errors import InputError

from ...registry import Registry
from ...scene import Scene


class Writer(Protocol):
    """An export format's writer: ``Writer(out, net)``, ``write(scene)`` per scene, ``close()``.
    ``reads_net``: whether it reads the scenes' SUMO net (``--net``; a format that does not refuses it)."""

    reads_net: ClassVar[bool]

    def __init__(self, out: Path, net: Path | None = None): ...

    def write(self, scene: Scene) -> None: ...

    def close(self) -> None: ...


#: every export format: name -> its writer class
EXPORT_FORMATS: Registry[type[Writer]] = Registry("export format", "--format")


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
