"""Which renderer a scene's frame comes from, by its source: the simulator's World (a SUMO or
highway-env scene, ray-cast on our meshes) or the RecordedWorld (a recording's scans, edited). Both
answer the same interface; callers ask :func:`world_for` and never the source."""
from __future__ import annotations

from typing import Iterable

from sumo_scenarios.log import SOURCES

from ..scene import Scene
from ..scene.recording import RECORDING_SOURCE
from .lidar_spec import LidarSpec
from .recorded import RecordedWorld
from .world import World

#: scene source -> its renderer class
RENDERERS = {**{source: World for source in SOURCES}, RECORDING_SOURCE: RecordedWorld}


def world_for(scene: Scene, spec: LidarSpec, movable_ids: Iterable[str] = ()) -> World | RecordedWorld:
    """The renderer of ``scene``'s frame (``movable_ids``: the agents a search may move)."""
    return RENDERERS[scene.source](scene, spec, movable_ids)
