"""A second, independent plausibility check of a written scene: shapely footprints only.

The search draws its feasible set with :class:`~asg.scene.feasibility.FeasibilityChecker` (python-fcl
boxes, the lane map's prepared drivable area, vectorised range test). Checking the final scene with
that same code could not catch its own mistakes, so this module re-derives every criterion from the
scene's raw data on another path:

- collisions: the moved vehicle's ground footprint (a shapely polygon from its corners) overlaps
  another agent's footprint or a building's footprint polygon by more than ``OVERLAP_M2``;
- off the drivable area: the footprint is not covered by the union of each lane's polygon (its
  centerline widened by half its width on each side) and each junction's outline, grown by the
  lane map's tolerance;
- out of range: the centre, rotated into the ego's frame by hand, lies beyond the evaluation range.

Frames: the network frame (x east, y north, metres), as the scene.
"""
from __future__ import annotations

import math

from shapely.geometry import LineString, Polygon
from shapely.ops import unary_union

from sumo_scenarios.lanes import DRIVABLE_TOLERANCE_M

from .agent import Agent
from .feasibility import EVAL_RANGE_M, Plausibility
from .scene import Scene

#: overlap (m²) below which two footprints count as touching, not colliding (float noise)
OVERLAP_M2 = 1e-6


def moved_vehicles(initial: Scene, final: Scene) -> list[Agent]:
    """The vehicles of ``final`` whose pose differs from ``initial``."""
    before = {a.agent_id: a for a in initial.agents}
    return [a for a in final.vehicles if a.agent_id in before
            and (a.x_m, a.y_m, a.yaw_rad) != (before[a.agent_id].x_m, before[a.agent_id].y_m, before[a.agent_id].yaw_rad)]


def _footprint(a: Agent) -> Polygon:
    c, s = math.cos(a.yaw_rad), math.sin(a.yaw_rad)
    hl, hw = a.length_m / 2, a.width_m / 2
    return Polygon([(a.x_m + c * u - s * v, a.y_m + s * u + c * v)
                    for u, v in ((hl, hw), (-hl, hw), (-hl, -hw), (hl, -hw))])


def _drivable(scene: Scene):
    pieces = [LineString(l.centerline_xy).buffer(l.width_m / 2, cap_style="flat")
              for l in scene.lane_map.lanes if len(l.centerline_xy) >= 2]
    pieces += [Polygon(j.shape_xy).buffer(0) for j in scene.lane_map.junctions if len(j.shape_xy) >= 3]
    return unary_union(pieces).buffer(DRIVABLE_TOLERANCE_M)


def _in_range(ego: Agent, a: Agent) -> bool:
    dx, dy = a.x_m - ego.x_m, a.y_m - ego.y_m
    c, s = math.cos(ego.yaw_rad), math.sin(ego.yaw_rad)
    return abs(c * dx + s * dy) <= EVAL_RANGE_M and abs(-s * dx + c * dy) <= EVAL_RANGE_M


def recheck(initial: Scene, final: Scene) -> Plausibility:
    """Collisions, off-road and out-of-range counts of the vehicles ``final`` moved (see module)."""
    moved = moved_vehicles(initial, final)
    if not moved:
        return Plausibility(0, 0, 0)
    moved_ids = {a.agent_id for a in moved}
    mine = {a.agent_id: _footprint(a) for a in moved}
    others = [_footprint(a) for a in final.agents if a.agent_id not in moved_ids]
    others += [Polygon(b.footprint_xy).convex_hull for b in final.buildings]
    collisions = 0
    for aid, fp in mine.items():
        hits_other = any(fp.intersection(o).area > OVERLAP_M2 for o in others)
        hits_moved = any(fp.intersection(g).area > OVERLAP_M2 for bid, g in mine.items() if bid != aid)
        collisions += hits_other or hits_moved
    drivable = _drivable(final)
    off_road = sum(not drivable.covers(fp) for fp in mine.values())
    out_of_range = sum(not _in_range(final.ego, a) for a in moved)
    return Plausibility(collisions, off_road, out_of_range)
