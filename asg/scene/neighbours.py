"""Which agents are near which: communication range, nearest collaborators."""
from __future__ import annotations

import math

from .agent import Agent
from .scene import Scene

#: default V2X communication range (m)
COMM_RANGE_M = 70.0


def vehicles_within(scene: Scene, center_id: str, range_m: float = COMM_RANGE_M) -> list[Agent]:
    """Vehicles (not ``center_id``) within ``range_m`` of agent ``center_id``, nearest first."""
    c = scene.agent(center_id)
    near = [a for a in scene.vehicles if a.agent_id != center_id and math.hypot(a.x_m - c.x_m, a.y_m - c.y_m) <= range_m]
    return sorted(near, key=lambda a: (math.hypot(a.x_m - c.x_m, a.y_m - c.y_m), a.agent_id))


def with_nearest_collaborators(scene: Scene, count: int, range_m: float = COMM_RANGE_M) -> Scene:
    """The scene with its collaborators set to the ``count`` nearest vehicles to the ego (fewer if
    fewer are in range); a scene that already names collaborators is returned as is."""
    if scene.collaborators or count <= 0:
        return scene
    return scene.with_collaborators([a.agent_id for a in vehicles_within(scene, scene.ego_id, range_m)[:count]])
