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
- out of range: the centre, rotated into the ego's frame by hand, lies beyond the evaluation range;
- at the ``traffic`` level, wrong way: the vehicle is not in a lane of its own direction (its
  centre on a lane heading within the configured angle, its corners on same-direction lanes or in
  a junction), with lane headings taken from the centerline by hand.

Frames: the network frame (x east, y north, metres), as the scene.
"""
from __future__ import annotations

import math

from shapely.geometry import LineString, Point, Polygon
from shapely.ops import unary_union

from sumo_scenarios.geometry import heading_gap_rad
from sumo_scenarios.lanes import DRIVABLE_TOLERANCE_M

from .agent import Agent
from .feasibility import EVAL_RANGE_M, Plausibility, PlausibilityLevel
from .scene import Scene

#: overlap (m²) below which two footprints count as touching, not colliding (float noise)
OVERLAP_M2 = 1e-6


def moved_vehicles(initial: Scene, final: Scene) -> list[Agent]:
    """The vehicles of ``final`` whose pose differs from ``initial``, and those it added."""
    before = {a.agent_id: a for a in initial.agents}
    return [a for a in final.vehicles if a.agent_id not in before
            or (a.x_m, a.y_m, a.yaw_rad) != (before[a.agent_id].x_m, before[a.agent_id].y_m, before[a.agent_id].yaw_rad)]


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


def _wrong_way(final: Scene, moved: list[Agent], max_heading_rad: float) -> int:
    """Moved vehicles not in a lane of their own direction: the centre on no lane (internal ones
    included) heading within ``max_heading_rad``, or a corner neither in a junction nor on a lane
    heading within 90 deg. Lane headings from points 0.25 m either side along the centerline."""
    lanes = [(LineString(l.centerline_xy), l.width_m) for l in final.lane_map.lanes if len(l.centerline_xy) >= 2]
    junctions = unary_union([Polygon(j.shape_xy).buffer(0) for j in final.lane_map.junctions
                             if len(j.shape_xy) >= 3]).buffer(DRIVABLE_TOLERANCE_M)

    def gaps(x: float, y: float, yaw: float) -> list[float]:
        pt, out = Point(x, y), []
        for line, width in lanes:
            if line.length > 0 and line.distance(pt) <= width / 2 + DRIVABLE_TOLERANCE_M:
                s = line.project(pt)
                a, b = line.interpolate(max(s - 0.25, 0.0)), line.interpolate(min(s + 0.25, line.length))
                out.append(heading_gap_rad(math.atan2(b.y - a.y, b.x - a.x), yaw))
        return out

    wrong = 0
    for a in moved:
        centre_ok = any(g <= max_heading_rad for g in gaps(a.x_m, a.y_m, a.yaw_rad))
        corners_ok = all(junctions.contains(Point(x, y)) or any(g < math.pi / 2 for g in gaps(x, y, a.yaw_rad))
                         for x, y in _footprint(a).exterior.coords[:-1])
        wrong += not (centre_ok and corners_ok)
    return wrong


def recheck(initial: Scene, final: Scene, plausibility: PlausibilityLevel = "paper", traffic_heading_deg: float = 30.0) -> Plausibility:
    """Collisions, off-road and out-of-range counts of the vehicles ``final`` moved or inserted (see module),
    and at the ``traffic`` level how many are not in a lane of their own direction."""
    moved = moved_vehicles(initial, final)
    traffic = plausibility == "traffic"
    if not moved:
        return Plausibility(0, 0, 0, 0 if traffic else None)
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
    wrong_way = _wrong_way(final, moved, math.radians(traffic_heading_deg)) if traffic else None
    return Plausibility(collisions, off_road, out_of_range, wrong_way)
