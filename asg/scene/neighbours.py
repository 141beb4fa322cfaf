"""Which agents are near which: communication range, nearest collaborators."""
from __future__ import annotations

import math
import numpy as np

from .agent import Agent
from .scene import Scene

#: default V2X communication range (m)
COMM_RANGE_M = 70.0


def vehicles_within(scene: Scene, center_id: str, range_m: float = COMM_RANGE_M) -> list[Agent]:
    """Vehicles (not ``center_id``) within ``range_m`` of agent ``center_id``, nearest first."""
    c = scene.agent(center_id)
    near = [a for a in scene.vehicles if a.agent_id != center_id and math.hypot(a.x_m - c.x_m, a.y_m - c.y_m) <= range_m]
    return sorted(near, key=lambda a: (math.hypot(a.x_m - c.x_m, a.y_m - c.y_m), a.agent_id))


def collaborator_candidates(scene: Scene, center_id: str, range_m: float = COMM_RANGE_M) -> list[Agent]:
    """The vehicles within ``range_m`` of ``center_id`` that can share a scan (every vehicle of a
    simulated scene; in a recording, those whose scan was recorded), nearest first."""
    return [a for a in vehicles_within(scene, center_id, range_m) if scene.can_sense(a.agent_id)]


def with_nearest_collaborators(scene: Scene, count: int, range_m: float = COMM_RANGE_M) -> Scene:
    """The scene with its collaborators set to the ``count`` nearest vehicles to the ego (fewer if
    fewer are in range); a scene that already names collaborators is returned as is."""
    if scene.collaborators or count <= 0:
        return scene
    return scene.with_collaborators([a.agent_id for a in collaborator_candidates(scene, scene.ego_id, range_m)[:count]])


def random_collaborators(scene: Scene, ego_id: str, count: int, rng: np.random.Generator,
                         range_m: float = COMM_RANGE_M) -> tuple[str, ...] | None:
    """``count`` vehicles drawn at random (without replacement) among those within ``range_m`` of
    ``ego_id``, in id order (fewer if fewer are in range; None if none is): how the data sets pick."""
    cands = sorted(a.agent_id for a in collaborator_candidates(scene, ego_id, range_m))
    if not cands:
        return None
    pick = rng.choice(len(cands), size=min(count, len(cands)), replace=False)
    return tuple(cands[i] for i in sorted(pick))
