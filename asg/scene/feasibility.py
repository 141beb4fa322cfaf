"""Plausibility of moved vehicles: on SUMO's drivable area, colliding with nothing (python-fcl), in range.

Collision geometry: every vehicle and RSU is an fcl Box of its size at its pose; each building an
fcl BVH prism of its footprint's convex hull (exact for the rectangular buildings we generate,
conservative otherwise), from the ground to its height.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal, Mapping, Sequence, get_args

import fcl
import numpy as np
from shapely.geometry import MultiPoint

from sumo_scenarios.buildings import Building
from sumo_scenarios.log import NEAR_RADIUS_M

from .agent import Agent, stacked_footprints_xy
from .scene import Scene

#: the evaluation range around the ego (|x|, |y| <= this in the ego frame), metres: what AP counts,
#: where moved vehicles must stay. The same number as the radius of "near the ego" when logs pick
#: an ego and count traffic (a circle, sumo_scenarios.log)
EVAL_RANGE_M = NEAR_RADIUS_M

#: how plausible a moved vehicle must be: "paper" (on a drivable lane, no collision) or "traffic"
#: (also in a lane of its own direction, heading along it); ``--plausibility``, space.plausibility
PlausibilityLevel = Literal["paper", "traffic"]
PLAUSIBILITY_LEVELS: tuple[str, ...] = get_args(PlausibilityLevel)


def box_object(a: Agent) -> fcl.CollisionObject:
    """``a``'s box as an fcl object (network frame)."""
    return box_object_at(a, a.x_m, a.y_m, a.yaw_rad)


def box_object_at(body: Agent, x_m: float, y_m: float, yaw_rad: float) -> fcl.CollisionObject:
    """The box of ``body``'s size and ground height, its centre at (``x_m``, ``y_m``) heading
    ``yaw_rad`` (network frame), as an fcl object."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return fcl.CollisionObject(fcl.Box(body.length_m, body.width_m, body.height_m),
                               fcl.Transform(rot, np.array([x_m, y_m, body.z_m + body.height_m / 2])))


def collide_boxes(a: fcl.CollisionObject, b: fcl.CollisionObject) -> bool:
    return fcl.collide(a, b, fcl.CollisionRequest(), fcl.CollisionResult()) > 0


def _building_object(b: Building) -> fcl.CollisionObject:
    hull = np.asarray(MultiPoint([tuple(p) for p in b.footprint_xy]).convex_hull.exterior.coords)[:-1]
    k = len(hull)
    verts = np.vstack([np.c_[hull, np.zeros(k)], np.c_[hull, np.full(k, b.height_m)]])
    tris = [[0, i, i + 1] for i in range(1, k - 1)] + [[k, k + i + 1, k + i] for i in range(1, k - 1)]
    for i in range(k):
        j = (i + 1) % k
        tris += [[i, j, k + j], [i, k + j, k + i]]
    model = fcl.BVHModel()
    model.beginModel(len(verts), len(tris))
    model.addSubModel(verts, np.array(tris, dtype=np.int64))
    model.endModel()
    return fcl.CollisionObject(model, fcl.Transform())


def in_eval_range(ego: Agent, agents: Sequence[Agent]) -> np.ndarray:
    """(n,) bool: box centres within |x|, |y| <= EVAL_RANGE_M in the ego's frame."""
    if not agents:
        return np.zeros(0, dtype=bool)
    return centres_in_eval_range(ego, np.array([[a.x_m, a.y_m] for a in agents]))


def centres_in_eval_range(ego: Agent, centres_xy: np.ndarray) -> np.ndarray:
    """(n,) bool: centres (n, 2) of the network frame within |x|, |y| <= EVAL_RANGE_M in the ego's frame."""
    xy = np.asarray(centres_xy, dtype=float).reshape(-1, 2) - np.array([ego.x_m, ego.y_m])
    c, s = math.cos(ego.yaw_rad), math.sin(ego.yaw_rad)
    local = np.stack([c * xy[:, 0] + s * xy[:, 1], -s * xy[:, 0] + c * xy[:, 1]], axis=1)
    return np.all(np.abs(local) <= EVAL_RANGE_M, axis=1)


@dataclass(frozen=True)
class Plausibility:
    collisions: int
    off_road: int
    out_of_range: int
    #: ``traffic`` level only: moved vehicles not in a lane of their own direction (None: not checked)
    wrong_way: int | None = None

    @property
    def ok(self) -> bool:
        return self.collisions == 0 and self.off_road == 0 and self.out_of_range == 0 and not self.wrong_way

    def to_dict(self) -> dict:
        out = {"collisions": self.collisions, "off_road": self.off_road, "out_of_range": self.out_of_range}
        return out if self.wrong_way is None else out | {"wrong_way": self.wrong_way}


class FeasibilityChecker:
    """Checks poses of the ``movable`` vehicles of a scene against everything else in it."""

    def __init__(self, scene: Scene, movable_ids: Sequence[str], plausibility: PlausibilityLevel = "paper",
                 traffic_heading_deg: float = 30.0):
        self.scene = scene
        self.movable_ids = tuple(movable_ids)
        self.traffic = plausibility == "traffic"
        self.max_heading_rad = math.radians(traffic_heading_deg)
        fixed = [a for a in scene.agents if a.agent_id not in self.movable_ids]
        self._static = fcl.DynamicAABBTreeCollisionManager()
        objs = [box_object(a) for a in fixed] + [_building_object(b) for b in scene.buildings]
        if objs:
            self._static.registerObjects(objs)
        self._static.setup()
        self._has_static = bool(objs)
        self._request = fcl.CollisionRequest()

    def collides(self, agents: Sequence[Agent]) -> int:
        """How many of ``agents`` touch something fixed or each other."""
        objs = [box_object(a) for a in agents]
        hit = self._pairwise_hits(objs)
        hit.update(i for i, o in enumerate(objs) if self.touches_fixed(o))
        return len(hit)

    def touches_fixed(self, box: fcl.CollisionObject) -> bool:
        """Does ``box`` (a moved vehicle's, from :func:`box_object`) touch a vehicle, RSU or
        building that does not move?"""
        if not self._has_static:
            return False
        data = fcl.CollisionData(request=self._request)
        self._static.collide(box, data, fcl.defaultCollisionCallback)
        return bool(data.result.is_collision)

    def _pairwise_hits(self, objs: list) -> set[int]:
        return {k for i, o in enumerate(objs) for j in range(i + 1, len(objs))
                if collide_boxes(o, objs[j]) for k in (i, j)}

    def in_range(self, centres_xy: np.ndarray) -> np.ndarray:
        """(n,) bool: box centres (n, 2) of the network frame within the evaluation range of the ego frame."""
        return centres_in_eval_range(self.scene.ego, centres_xy)

    def on_road(self, centres_xy: np.ndarray, yaws_rad: np.ndarray, length_m, width_m) -> np.ndarray:
        """(n,) bool: boxes given as arrays (centres (n, 2), headings (n,), lengths and widths (n,)
        or one for all) on the drivable area and, at the ``traffic`` level, in a lane of their own
        direction."""
        footprints_xy = stacked_footprints_xy(centres_xy[:, 0], centres_xy[:, 1], yaws_rad, length_m, width_m)
        ok = self.scene.lane_map.footprints_on_road(footprints_xy)
        if self.traffic:  # the costlier lane-direction test only where the area test passed
            idx = np.flatnonzero(ok)
            if len(idx):
                ok[idx] = self._in_own_lanes(centres_xy[idx], yaws_rad[idx], footprints_xy[idx])
        return ok

    def _in_own_lanes(self, centres_xy: np.ndarray, yaws_rad: np.ndarray, footprints_xy: np.ndarray) -> np.ndarray:
        """(n,) bool: in a lane of its own direction (see LaneMap.in_own_lane)."""
        return self.scene.lane_map.in_own_lanes(centres_xy, yaws_rad, footprints_xy, self.max_heading_rad)

    def check(self, moved: Mapping[str, Agent]) -> Plausibility:
        """Collisions, off-road and out-of-range counts of the ``moved`` vehicles (by id) at their
        poses, and at the ``traffic`` level the wrong-way count."""
        agents = [moved[i] for i in self.movable_ids if i in moved]
        if not agents:
            return Plausibility(0, 0, 0, 0 if self.traffic else None)
        centres_xy = np.array([[a.x_m, a.y_m] for a in agents], dtype=float)
        yaws_rad = np.array([a.yaw_rad for a in agents], dtype=float)
        footprints_xy = stacked_footprints_xy(centres_xy[:, 0], centres_xy[:, 1], yaws_rad,
                                              [a.length_m for a in agents], [a.width_m for a in agents])
        on_area = self.scene.lane_map.footprints_on_road(footprints_xy)
        wrong_way = int((~self._in_own_lanes(centres_xy, yaws_rad, footprints_xy)).sum()) if self.traffic else None
        return Plausibility(self.collides(agents), int((~on_area).sum()), int((~self.in_range(centres_xy)).sum()),
                            wrong_way)
