"""Roadside units (RSUs): LiDAR on a pole at a junction corner, just off the drivable area."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np
import shapely
from shapely.geometry import Point

from . import checks
from .buildings import Building
from .errors import InputError
from .lanes import LaneMap

#: height of an RSU's LiDAR above the ground (m), on its pole
RSU_POLE_HEIGHT_M = 4.5
#: keep this clear of lanes (m): the pole stands on the kerb
RSU_CLEARANCE_M = 1.0


@dataclass(frozen=True)
class RoadsideUnit:
    """An RSU: pole foot at (x_m, y_m) in the network frame, LiDAR ``height_m`` above it."""

    rsu_id: str
    x_m: float
    y_m: float
    junction_id: str
    height_m: float = RSU_POLE_HEIGHT_M

    def to_dict(self) -> dict:
        return {"id": self.rsu_id, "x_m": round(self.x_m, 3), "y_m": round(self.y_m, 3),
                "junction": self.junction_id, "height_m": self.height_m}

    @staticmethod
    def from_dict(d: dict, where: str = "rsu") -> "RoadsideUnit":
        """An RSU from its mapping (a log's meta.yaml): its id a safe name (it names scenes and
        their files), its numbers finite and in range; InputError naming ``where`` otherwise."""
        if not isinstance(d, dict) or not {"id", "x_m", "y_m", "junction", "height_m"} <= set(d):
            raise InputError(f"{where}: expected a mapping with id, x_m, y_m, junction and height_m")
        rsu_id = checks.safe_id(d["id"], where)
        at = f"{where} {rsu_id}"
        height_m = checks.number(d["height_m"], f"{at} height_m", 0.0, checks.SIZE_LIMITS_M["height_m"], lo_open=True)
        return RoadsideUnit(rsu_id, checks.coordinate(d["x_m"], f"{at} x_m"), checks.coordinate(d["y_m"], f"{at} y_m"),
                            str(d["junction"]), height_m)


def place_rsus(lane_map: LaneMap, buildings: Sequence[Building], max_count: int = 8,
               min_separation_m: float = 90.0) -> list[RoadsideUnit]:
    """Put RSUs at the busiest-looking junctions (signalised first, then most lanes), spread apart.

    Each stands at the nearest kerb point to its junction centre: the smallest radius, over 32
    directions, at which a point is ``RSU_CLEARANCE_M`` off the drivable area and outside buildings.
    Lane maps without junctions (highway-env's straight roads) get RSUs every ``min_separation_m``
    along their first lane instead.
    """
    keep_out = lane_map.drivable.buffer(RSU_CLEARANCE_M)
    blocked = shapely.union_all([shapely.Polygon(b.footprint_xy) for b in buildings] + [keep_out])
    shapely.prepare(blocked)
    sites = _junction_sites(lane_map)
    chosen: list[RoadsideUnit] = []
    for site_id, cx, cy in sites:
        if any(math.hypot(cx - r.x_m, cy - r.y_m) < min_separation_m for r in chosen):
            continue
        spot = _kerb_point(blocked, cx, cy)
        if spot is None:
            continue
        chosen.append(RoadsideUnit(f"rsu{len(chosen)}", spot[0], spot[1], site_id))
        if len(chosen) >= max_count:
            break
    return chosen


def _junction_sites(lane_map: LaneMap) -> list[tuple[str, float, float]]:
    """Candidate RSU sites (id, x, y), best first."""
    incident: dict[str, int] = {}
    for lane in lane_map.lanes:
        if lane.internal:
            # internal lanes are named ':JUNCTION_k_l'
            jid = lane.lane_id[1:].rsplit("_", 2)[0]
            incident[jid] = incident.get(jid, 0) + 1
    real = [j for j in lane_map.junctions if j.kind not in ("dead_end", "internal")]
    if real:
        ranked = sorted(real, key=lambda j: (j.kind != "traffic_light", -incident.get(j.junction_id, 0), j.junction_id))
        return [(j.junction_id, j.center_xy[0], j.center_xy[1]) for j in ranked]
    sites = []
    for lane, line in lane_map.road_edges():
        for k, s in enumerate(np.arange(40.0, line.length, 150.0)):
            p = line.interpolate(float(s))
            sites.append((f"{lane.lane_id}@{k}", p.x, p.y))
        break
    return sites


def _kerb_point(blocked, cx: float, cy: float) -> tuple[float, float] | None:
    best = None
    for k in range(32):
        a = 2 * math.pi * (k + 0.5) / 32
        for r in np.arange(2.0, 40.0, 0.5):
            x, y = cx + r * math.cos(a), cy + r * math.sin(a)
            if not blocked.contains(Point(x, y)):
                if best is None or r < best[0]:
                    best = (r, x, y)
                break
    return None if best is None else (float(best[1]), float(best[2]))
