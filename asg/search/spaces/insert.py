"""``insert``: up to K vehicles added on free lane positions.

Each of the K slots is either absent or a vehicle of one of the scene's own types (its type, size and
ground height copied from a vehicle of the scene, drawn once per slot), its centre on a lane's centerline (not an
internal junction lane), heading along the lane, speed the lane's limit. Inserted vehicles pass the
same plausibility tests as moved ones (drivable area, no collision with anything, in range; at the
``traffic`` level in a lane of their own direction, which a lane-aligned vehicle is).

Normalised slot (4,): presence (-1 absent, +1 present), centre x and y in the ego's frame divided by
the evaluation range, heading divided by pi. A slot's candidates are present half the time.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from shapely.geometry import LineString, Point

from sumo_scenarios import checks

from ...scene import Agent
from ...scene.feasibility import EVAL_RANGE_M
from .base import SPACES, PerturbationSpace, Slot

#: inserted vehicles are named INSERT_PREFIX + slot number
INSERT_PREFIX = "asg-insert-"


@dataclass(frozen=True)
class InsertConfig:
    #: K: vehicles a member may insert (each slot present or absent)
    max_vehicles: int = 3

    def __post_init__(self) -> None:
        checks.number(self.max_vehicles, "space.insert.max_vehicles", 1, 32)


class InsertSlot(Slot):
    width = 4

    def __init__(self, agent_id: str, template: Agent, ctx_scene, lanes: list[tuple[LineString, object]]):
        self.agent_id = agent_id
        self.template = self.body = template
        self.scene = ctx_scene
        self.lanes = lanes
        self.lengths = np.array([line.length for line, _ in lanes])
        self.radius_m = 0.5 * math.hypot(template.length_m, template.width_m)
        ego = ctx_scene.ego
        self._c, self._s = math.cos(ego.yaw_rad), math.sin(ego.yaw_rad)
        self._ego_xy = (ego.x_m, ego.y_m)

    def draw(self, rng: np.random.Generator, n: int) -> np.ndarray:
        out = np.tile(self.identity(), (n, 1))
        if not len(self.lanes):
            return out
        present = np.flatnonzero(rng.random(n) < 0.5)
        lane_idx = rng.choice(len(self.lanes), size=len(present), p=self.lengths / self.lengths.sum())
        stations = rng.random(len(present)) * self.lengths[lane_idx]
        for row, k, s in zip(present, lane_idx, stations):
            line, lane = self.lanes[k]
            pt = line.interpolate(s)
            a, b = line.interpolate(max(s - 0.25, 0.0)), line.interpolate(min(s + 0.25, line.length))
            heading = math.atan2(b.y - a.y, b.x - a.x)
            dx, dy = pt.x - self._ego_xy[0], pt.y - self._ego_xy[1]
            out[row] = (1.0, (self._c * dx + self._s * dy) / EVAL_RANGE_M, (-self._s * dx + self._c * dy) / EVAL_RANGE_M,
                        heading / math.pi)
        return out

    def agent(self, x: np.ndarray) -> Agent | None:
        if x[0] <= 0:
            return None
        u, v = x[1] * EVAL_RANGE_M, x[2] * EVAL_RANGE_M
        px, py = self._ego_xy[0] + self._c * u - self._s * v, self._ego_xy[1] + self._s * u + self._c * v
        where = self.scene.lane_map.locate(px, py, include_internal=False)
        lane = self.scene.lane_map.lane(where.lane_id) if where is not None else None
        return replace(self.template, agent_id=self.agent_id, x_m=float(px), y_m=float(py), yaw_rad=float(x[3] * math.pi),
                       speed_mps=float(lane.speed_mps) if lane is not None else 0.0,
                       lane_id=lane.lane_id if lane is not None else None)

    def identity(self) -> np.ndarray:
        return np.array([-1.0, 0.0, 0.0, 0.0])

    def readable(self, x: np.ndarray) -> list[float]:
        a = self.agent(x)
        return [0.0, 0.0, 0.0, 0.0] if a is None else [1.0, round(a.x_m, 4), round(a.y_m, 4), round(math.degrees(a.yaw_rad), 4)]

    def columns(self) -> list[str]:
        return [f"{self.agent_id}_{k}" for k in ("present", "x_m", "y_m", "yaw_deg")]


@SPACES.register("insert")
class InsertSpace(PerturbationSpace):
    needs_lanes = True

    @property
    def slots(self) -> list[InsertSlot]:
        scene = self.ctx.scene
        k = self.cfg.insert.max_vehicles
        kinds = sorted((a for a in scene.vehicles if a.agent_id != scene.ego_id), key=lambda a: a.agent_id)
        if not kinds:
            return []
        lanes = _lanes_near_ego(scene)
        # slot i copies the type of a vehicle picked by a generator of its own (same scene, same slots)
        rng = np.random.default_rng([k, len(kinds)])
        templates = [kinds[int(rng.integers(len(kinds)))] for _ in range(k)]
        return [InsertSlot(f"{INSERT_PREFIX}{i}", t, scene, lanes) for i, t in enumerate(templates)]

    def bounds(self) -> dict:
        return {"max_vehicles": self.cfg.insert.max_vehicles}


def _lanes_near_ego(scene) -> list[tuple[LineString, object]]:
    """The non-internal lanes with a centerline point within the evaluation range (plus a car's
    length) of the ego, as (centerline, lane)."""
    ego = scene.ego
    reach = EVAL_RANGE_M * math.sqrt(2) + 5.0
    out = []
    for lane in scene.lane_map.lanes:
        if lane.internal or len(lane.centerline_xy) < 2:
            continue
        line = LineString(lane.centerline_xy)
        if line.length > 0 and line.distance(Point(ego.x_m, ego.y_m)) <= reach:
            out.append((line, lane))
    return out
