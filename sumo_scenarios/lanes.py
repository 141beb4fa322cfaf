"""Lane geometry and the drivable area: the lane service that every later stage asks.

Coordinates are SUMO's network frame: x east, y north, metres; headings in radians,
counter-clockwise from +x (``yaw_rad``). A :class:`LaneMap` is built from a SUMO net
(:func:`LaneMap.from_sumo_net`) or from plain lane polylines (highway-env), and answers:

- is this footprint on the drivable area (lanes and junction shapes)?
- which lane, station and lateral offset does a point have, and the lane's heading there?
"""
from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np
import shapely
from shapely.geometry import LineString, Point, Polygon
from shapely.ops import unary_union

from . import checks
from .errors import InputError
from .geometry import heading_gap_rad

#: slack when testing a footprint against the drivable area (m): SUMO's lane and junction shapes
#: meet with small gaps and slivers.
DRIVABLE_TOLERANCE_M = 0.15


@dataclass(frozen=True)
class Lane:
    """One lane: ``centerline_xy`` (N, 2) metres in the network frame, in driving direction."""

    lane_id: str
    centerline_xy: np.ndarray
    width_m: float
    speed_mps: float
    internal: bool = False

    def to_dict(self) -> dict:
        return {
            "id": self.lane_id,
            "width_m": float(self.width_m),
            "speed_mps": float(self.speed_mps),
            "internal": bool(self.internal),
            "centerline": [[float(x), float(y)] for x, y in self.centerline_xy],
        }

    @staticmethod
    def from_dict(d: dict) -> "Lane":
        where = f"lane {str(d['id'])[:40]!r}"
        return Lane(
            lane_id=str(d["id"]),
            centerline_xy=checks.points_xy(d["centerline"], f"{where} centerline", 2),
            width_m=checks.number(d["width_m"], f"{where} width_m", 0.0, 50.0, lo_open=True),
            speed_mps=checks.number(d["speed_mps"], f"{where} speed_mps", 0.0, 150.0),
            internal=bool(d.get("internal", False)),
        )


@dataclass(frozen=True)
class Junction:
    """A junction's outline ``shape_xy`` (M, 2) metres, and its kind (``traffic_light``, ``priority``...)."""

    junction_id: str
    shape_xy: np.ndarray
    kind: str
    center_xy: tuple[float, float]

    def to_dict(self) -> dict:
        return {
            "id": self.junction_id,
            "kind": self.kind,
            "center": [float(self.center_xy[0]), float(self.center_xy[1])],
            "shape": [[float(x), float(y)] for x, y in self.shape_xy],
        }

    @staticmethod
    def from_dict(d: dict) -> "Junction":
        where = f"junction {str(d['id'])[:40]!r}"
        c = checks.points_xy([d["center"]], f"{where} center", 1)[0]
        return Junction(
            junction_id=str(d["id"]),
            shape_xy=checks.points_xy(d["shape"], f"{where} shape", 0) if len(d["shape"]) else np.zeros((0, 2)),
            kind=str(d["kind"]),
            center_xy=(float(c[0]), float(c[1])),
        )


@dataclass(frozen=True)
class LanePosition:
    """Where a point lies relative to its nearest lane.

    ``station_m``: distance along the centerline; ``lateral_m``: signed offset, left of the
    driving direction positive; ``heading_rad``: the lane's heading there; ``on_lane``: the point is
    within half the lane width of the centerline.
    """

    lane_id: str
    station_m: float
    lateral_m: float
    heading_rad: float
    on_lane: bool


def _polygon(shape_xy: np.ndarray) -> Polygon | None:
    if len(shape_xy) < 3:
        return None
    poly = Polygon(shape_xy)
    if not poly.is_valid:
        poly = poly.buffer(0)
    return poly if poly.area > 1e-6 else None


class LaneMap:
    """Lanes and junctions with spatial indexes; see the module docstring for the queries."""

    def __init__(self, lanes: Sequence[Lane], junctions: Sequence[Junction] = ()):
        self.lanes: tuple[Lane, ...] = tuple(lanes)
        self.junctions: tuple[Junction, ...] = tuple(junctions)
        self._lines = [LineString(l.centerline_xy) for l in self.lanes]
        self._lane_tree = shapely.STRtree(self._lines) if self._lines else None
        self._line_array = np.array(self._lines, dtype=object)
        self._line_lengths = shapely.length(self._line_array) if self._lines else np.zeros(0)
        #: how far (m) from its centerline a point is on each lane
        self._reach_m = np.array([l.width_m / 2.0 + DRIVABLE_TOLERANCE_M for l in self.lanes])
        #: per lane index, its centerline's stations and segment headings (_centerline_steps), when first asked
        self._steps: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        pieces = [
            line.buffer(lane.width_m / 2.0, cap_style="flat", join_style="round")
            for line, lane in zip(self._lines, self.lanes)
            if line.length > 0
        ]
        pieces += [p for p in (_polygon(j.shape_xy) for j in self.junctions) if p is not None]
        self.drivable = unary_union(pieces) if pieces else Polygon()
        self._drivable_loose = self.drivable.buffer(DRIVABLE_TOLERANCE_M)
        shapely.prepare(self._drivable_loose)
        self._by_id = {l.lane_id: i for i, l in enumerate(self.lanes)}
        self._max_half_width_m = max((l.width_m / 2.0 for l in self.lanes), default=0.0)
        junctions = [p for p in (_polygon(j.shape_xy) for j in self.junctions) if p is not None]
        self._junctions_loose = unary_union(junctions).buffer(DRIVABLE_TOLERANCE_M) if junctions else Polygon()
        shapely.prepare(self._junctions_loose)

    # ---- construction ------------------------------------------------------------------------
    @staticmethod
    def from_sumo_net(net_path: str | Path) -> "LaneMap":
        """Read lanes (including internal junction lanes) and junction shapes from a ``.net.xml``,
        each checked as :meth:`Lane.from_dict` and :meth:`Junction.from_dict` check a scene's (a net is
        a file a user hands in: a NaN in a shape would become scenes that cannot be loaded)."""
        root = parse_net_root(net_path)
        try:
            lane_map = LaneMap._from_net_root(root)
        except InputError as exc:
            raise InputError(f"{net_path}: {exc}") from None
        if not any(not lane.internal for lane in lane_map.lanes):
            raise InputError(f"{net_path}: the net has no lanes for cars; give a SUMO net with roads")
        return lane_map

    @staticmethod
    def _from_net_root(root: ET.Element) -> "LaneMap":
        lanes: list[Lane] = []
        for edge in root.iter("edge"):
            internal = edge.get("function") == "internal"
            if edge.get("function") in ("walkingarea", "crossing"):
                continue
            for lane in edge.iter("lane"):
                allow = lane.get("allow", "")
                if allow and "passenger" not in allow and "all" not in allow:
                    continue
                if "passenger" in lane.get("disallow", "").split():
                    continue
                where = f"lane {str(lane.get('id'))[:40]!r}"
                xy = _parse_shape(lane.get("shape", ""), where)
                if len(xy) < 2:
                    continue
                lanes.append(Lane.from_dict({
                    "id": lane.get("id"), "centerline": xy, "internal": internal,
                    "width_m": _number_attribute(lane, "width", 3.2, where),
                    "speed_mps": _number_attribute(lane, "speed", 13.89, where)}))
        junctions = []
        for j in root.iter("junction"):
            where = f"junction {str(j.get('id'))[:40]!r}"
            shape = _parse_shape(j.get("shape", ""), where)
            if j.get("type") in ("internal", "dead_end") and (j.get("type") == "internal" or len(shape) < 3):
                continue
            junctions.append(Junction.from_dict({
                "id": j.get("id"), "shape": shape, "kind": j.get("type", "priority"),
                "center": [_number_attribute(j, "x", 0.0, where), _number_attribute(j, "y", 0.0, where)]}))
        return LaneMap(lanes, junctions)

    def to_dict(self) -> dict:
        return {"lanes": [l.to_dict() for l in self.lanes], "junctions": [j.to_dict() for j in self.junctions]}

    @staticmethod
    def from_dict(d: dict) -> "LaneMap":
        return LaneMap(
            [Lane.from_dict(x) for x in d.get("lanes", [])],
            [Junction.from_dict(x) for x in d.get("junctions", [])],
        )

    def translated(self, dx_m: float, dy_m: float) -> "LaneMap":
        """The same lanes and junctions moved by (dx_m, dy_m) (another frame's origin)."""
        shift = np.array([dx_m, dy_m])
        return LaneMap([replace(l, centerline_xy=l.centerline_xy + shift) for l in self.lanes],
                       [replace(j, shape_xy=j.shape_xy + shift if len(j.shape_xy) else j.shape_xy,
                                center_xy=(j.center_xy[0] + dx_m, j.center_xy[1] + dy_m)) for j in self.junctions])

    def crop(self, center_xy: tuple[float, float], radius_m: float) -> "LaneMap":
        """The lanes and junctions that come within ``radius_m`` of ``center_xy`` (kept whole)."""
        disk = Point(center_xy).buffer(radius_m)
        lanes = [l for l, line in zip(self.lanes, self._lines) if line.intersects(disk)]
        junctions = [
            j for j in self.junctions if Point(j.center_xy).distance(Point(center_xy)) <= radius_m + 50.0
        ]
        return LaneMap(lanes, junctions)

    # ---- queries -----------------------------------------------------------------------------
    def lane(self, lane_id: str) -> Lane:
        return self.lanes[self._by_id[lane_id]]

    def footprint_on_road(self, footprint_xy: np.ndarray) -> bool:
        """True if the polygon ``footprint_xy`` (K, 2) lies on lanes and junctions (within tolerance)."""
        return bool(self._drivable_loose.contains(Polygon(footprint_xy)))

    def footprints_on_road(self, footprints_xy: np.ndarray) -> np.ndarray:
        """Vectorised :meth:`footprint_on_road`: (B, K, 2) footprints → (B,) bool."""
        polys = shapely.polygons(np.asarray(footprints_xy, dtype=float))
        return shapely.contains(self._drivable_loose, polys)

    def point_on_road(self, x_m: float, y_m: float) -> bool:
        return bool(self._drivable_loose.contains(Point(x_m, y_m)))

    def locate(self, x_m: float, y_m: float, include_internal: bool = True) -> LanePosition | None:
        """Nearest lane to a point, with station, signed lateral offset and heading there."""
        if self._lane_tree is None:
            return None
        pt = Point(x_m, y_m)
        idx = self._lane_tree.query_nearest(pt, all_matches=True)
        candidates = [int(i) for i in np.atleast_1d(idx)]
        if not include_internal:
            candidates = [i for i in candidates if not self.lanes[i].internal] or candidates
        best = min(candidates, key=lambda i: (self.lanes[i].internal, self.lanes[i].lane_id))
        line = self._lines[best]
        lane = self.lanes[best]
        s = line.project(pt)
        heading = self._heading_of(best, s)
        foot = line.interpolate(s)
        dx, dy = x_m - foot.x, y_m - foot.y
        lateral = -math.sin(heading) * dx + math.cos(heading) * dy
        return LanePosition(lane.lane_id, float(s), float(lateral), float(heading), abs(lateral) <= lane.width_m / 2.0)

    def directions_at_many(self, xy: np.ndarray) -> list[list[float]]:
        """Per point of ``xy`` (n, 2), the headings (rad) of every lane, internal ones included, whose
        area (centerline widened by half its width, within tolerance) holds it; the index and GEOS
        asked once for all the points."""
        xy = np.asarray(xy, dtype=float).reshape(-1, 2)
        out: list[list[float]] = [[] for _ in range(len(xy))]
        if self._lane_tree is None or not len(xy):
            return out
        points = shapely.points(xy)
        at, lane = self._lane_tree.query(points, predicate="dwithin", distance=self._max_half_width_m + DRIVABLE_TOLERANCE_M)
        lines = self._line_array[lane]
        inside = (self._line_lengths[lane] > 0) & (shapely.distance(lines, points[at]) <= self._reach_m[lane])
        at, lane = at[inside], lane[inside]
        for p, h in zip(at.tolist(), self._headings_of(lane, shapely.line_locate_point(lines[inside], points[at])).tolist()):
            out[p].append(h)
        return out

    def in_own_lane(self, center_xy: tuple[float, float], yaw_rad: float, footprint_xy: np.ndarray,
                    max_heading_rad: float) -> bool:
        """The ``traffic`` plausibility of a vehicle: its centre on a lane (internal lanes count)
        heading within ``max_heading_rad`` of its yaw, and each corner of its footprint on a lane
        of its own direction (within 90 deg: a neighbouring lane of the same road, as in a lane
        change) or inside a junction."""
        return bool(self.in_own_lanes(np.array([center_xy]), np.array([yaw_rad]), np.asarray(footprint_xy)[None],
                                      max_heading_rad)[0])

    def in_own_lanes(self, centres_xy: np.ndarray, yaws_rad: np.ndarray, footprints_xy: np.ndarray,
                     max_heading_rad: float) -> np.ndarray:
        """(n,) bool: :meth:`in_own_lane` of n vehicles (centres (n, 2), yaws (n,), footprints
        (n, K, 2)), with one query of the lanes and junctions for all their points."""
        n, corners = len(centres_xy), np.asarray(footprints_xy, dtype=float).reshape(len(centres_xy), -1, 2)
        headings = self.directions_at_many(np.concatenate([np.asarray(centres_xy, dtype=float).reshape(-1, 2),
                                                           corners.reshape(-1, 2)]))
        junction = shapely.contains_xy(self._junctions_loose, corners[..., 0], corners[..., 1])  # (n, K)
        per_corner = corners.shape[1]
        out = np.zeros(n, dtype=bool)
        for k in range(n):
            yaw = float(yaws_rad[k])
            corner_headings = headings[n + k * per_corner: n + (k + 1) * per_corner]
            along = [any(heading_gap_rad(h, yaw) < math.pi / 2 for h in hs) for hs in corner_headings]
            out[k] = (any(heading_gap_rad(h, yaw) <= max_heading_rad for h in headings[k])
                      and all(j or a for j, a in zip(junction[k], along)))
        return out

    def heading_at(self, lane_id: str, s_m: float) -> float:
        """The heading (rad) of lane ``lane_id``'s centerline at station ``s_m`` (the segment's
        there; a zero-length segment takes the one before it)."""
        return self._heading_of(self._by_id[lane_id], s_m)

    def _heading_of(self, index: int, s_m: float) -> float:
        return float(self._headings_of(np.array([index]), np.array([s_m]))[0])

    def _headings_of(self, lanes: np.ndarray, s_m: np.ndarray) -> np.ndarray:
        """(n,) headings (rad) of lanes (n,) (indices) at stations ``s_m`` (n,), grouped by lane."""
        out = np.zeros(len(lanes))
        for index in np.unique(lanes).tolist():
            steps = self._steps.get(index)
            if steps is None:
                steps = self._steps[index] = _centerline_steps(self.lanes[index].centerline_xy)
            cum_m, heading_rad = steps
            rows = np.flatnonzero(lanes == index)
            out[rows] = heading_rad[np.clip(np.searchsorted(cum_m, s_m[rows], side="right") - 1, 0, len(heading_rad) - 1)]
        return out

    def lane_km(self) -> float:
        """Total length of the non-internal lanes, km."""
        return sum(line.length for _, line in self.road_edges()) / 1000.0

    def bounds(self) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax) of the drivable area, metres."""
        return tuple(float(v) for v in self.drivable.bounds)  # type: ignore[return-value]

    def road_edges(self) -> Iterable[tuple[Lane, LineString]]:
        """Non-internal lanes with their centerlines."""
        return ((l, line) for l, line in zip(self.lanes, self._lines) if not l.internal)


def _centerline_steps(xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A centerline's (P, 2) station (m) at each vertex (P,) and the heading (rad) of each of its
    P - 1 segments, a zero-length one taking the heading of the nearest earlier one of length."""
    seg_len = np.hypot(*np.diff(xy, axis=0).T)
    heading = []
    for k in range(len(seg_len)):
        j = k
        while seg_len[j] == 0 and j > 0:
            j -= 1
        d = xy[j + 1] - xy[j]
        heading.append(math.atan2(d[1], d[0]))
    return np.concatenate([[0.0], np.cumsum(seg_len)]), np.array(heading)


def _parse_shape(text: str, where: str) -> np.ndarray:
    """A SUMO shape ``"x,y[,z] x,y[,z] ..."`` as an (N, 2) array; InputError naming ``where`` if it is not."""
    pts = [p.split(",") for p in text.split()]
    if not pts:
        return np.zeros((0, 2))
    try:
        return np.asarray([[float(p[0]), float(p[1])] for p in pts], dtype=float)
    except (ValueError, IndexError):
        raise InputError(f"{where}: shape {text[:40]!r} is not x,y pairs") from None


def _number_attribute(elem: ET.Element, name: str, default: float, where: str) -> float:
    """An element's numeric attribute (``default`` when absent), parsed; range checks are the caller's."""
    text = elem.get(name)
    if text is None:
        return default
    try:
        return float(text)
    except ValueError:
        raise InputError(f"{where}: {name} {text[:30]!r} is not a number") from None


def parse_net_root(net_path: str | Path) -> ET.Element:
    """Parse a SUMO ``.net.xml``; a missing, truncated or non-XML file raises InputError."""
    p = Path(net_path)
    if not p.is_file():
        raise InputError(f"{p}: net file not found; check the path or run 'asg towns list'")
    try:
        root = ET.parse(p).getroot()
    except ET.ParseError as exc:
        raise InputError(f"{p}: not a readable SUMO net ({exc}); rebuild it with netconvert") from None
    if root.tag != "net":
        raise InputError(f"{p}: not a SUMO net (root element <{root.tag}>, expected <net>); give a .net.xml")
    return root
