"""Procedural buildings beside the roads, stored as SUMO polygons (``<poly type="building">``).

Buildings are the static occluders of the 3D world. Footprints are rectangles lined up along the
lanes at a set-back from the drivable area; none touches a lane or a junction. Heights are in a
``<param key="height">`` child of each polygon (metres).
"""
from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
import shapely
from shapely.geometry import Polygon

from . import checks
from .atomic import write_text_atomic
from .errors import InputError
from .lanes import LaneMap


@dataclass(frozen=True)
class Building:
    """A building: ``footprint_xy`` (K, 2) metres, counter-clockwise, network frame; ``height_m``."""

    building_id: str
    footprint_xy: np.ndarray
    height_m: float

    def to_dict(self) -> dict:
        return {
            "id": self.building_id,
            "height_m": float(self.height_m),
            "footprint": [[float(x), float(y)] for x, y in self.footprint_xy],
        }

    @staticmethod
    def from_dict(d: dict) -> "Building":
        where = f"building {str(d['id'])[:40]!r}"
        footprint = checks.points_xy(d["footprint"], f"{where} footprint", 3)
        if Polygon(footprint).convex_hull.area < 1e-3:
            raise InputError(f"{where}: its footprint encloses no area; give at least 3 corners that are not in a line")
        return Building(str(d["id"]), footprint,
                        checks.number(d["height_m"], f"{where} height_m", 0.0, 1000.0, lo_open=True))


@dataclass(frozen=True)
class BuildingParams:
    """How buildings are laid out: gaps and size ranges in metres."""

    setback_m: float = 2.5
    spacing_m: float = 4.0
    length_m: tuple[float, float] = (10.0, 30.0)
    depth_m: tuple[float, float] = (8.0, 18.0)
    height_m: tuple[float, float] = (4.0, 30.0)
    fill_probability: float = 0.85

    def check(self, where: str) -> None:
        """InputError naming ``where`` unless every gap and size is within reach of a town's
        buildings (sizes 0.5-1,000 m, each range from low to high, a share in [0, 1])."""
        checks.number(self.setback_m, f"{where}.setback_m", 0.0, 100.0)
        checks.number(self.spacing_m, f"{where}.spacing_m", 0.5, 1000.0)
        for key in ("length_m", "depth_m", "height_m"):
            low, high = (checks.number(v, f"{where}.{key}", 0.5, 1000.0) for v in getattr(self, key))
            if low > high:
                raise InputError(f"{where}.{key}: [{low:g}, {high:g}] runs from high to low")
        checks.number(self.fill_probability, f"{where}.fill_probability", 0.0, 1.0)


def _rectangle(cx: float, cy: float, heading: float, length: float, depth: float) -> np.ndarray:
    c, s = math.cos(heading), math.sin(heading)
    local = np.array([[-length / 2, -depth / 2], [length / 2, -depth / 2], [length / 2, depth / 2], [-length / 2, depth / 2]])
    rot = np.array([[c, -s], [s, c]])
    return local @ rot.T + np.array([cx, cy])


def generate_buildings(lane_map: LaneMap, seed: int, params: BuildingParams = BuildingParams()) -> list[Building]:
    """Line both sides of every road lane with rectangular buildings that keep off the drivable area.

    Deterministic for a given lane map, seed and params.
    """
    rng = np.random.default_rng(seed)
    keep_out = lane_map.drivable.buffer(params.setback_m)
    shapely.prepare(keep_out)
    placed: list[Polygon] = []
    grid: dict[tuple[int, int], list[int]] = {}
    cell = 40.0
    buildings: list[Building] = []
    kerb_lanes = [(l, line) for l, line in lane_map.road_edges() if l.lane_id.endswith("_0")]
    for lane, line in sorted(kerb_lanes or lane_map.road_edges(), key=lambda t: t[0].lane_id):
        s = float(rng.uniform(0.0, params.spacing_m))
        while s < line.length:
            length = float(rng.uniform(*params.length_m))
            depth = float(rng.uniform(*params.depth_m))
            side = -1.0  # right of the rightmost lane: the kerb side in right-hand traffic
            take = rng.random() < params.fill_probability
            height = float(math.exp(rng.uniform(math.log(params.height_m[0]), math.log(params.height_m[1]))))
            centre_s = s + length / 2
            s += length + params.spacing_m
            if not take or centre_s > line.length:
                continue
            p = line.interpolate(centre_s)
            heading = lane_map.heading_at(lane.lane_id, centre_s)
            offset = lane.width_m / 2 + params.setback_m + depth / 2 + 0.5
            cx = p.x - side * math.sin(heading) * offset
            cy = p.y + side * math.cos(heading) * offset
            rect = _rectangle(cx, cy, heading, length, depth)
            poly = Polygon(rect)
            if keep_out.intersects(poly):
                continue
            x0, y0, x1, y1 = poly.bounds
            cells = [(i, j) for i in range(int(x0 // cell), int(x1 // cell) + 1) for j in range(int(y0 // cell), int(y1 // cell) + 1)]
            near = {k for c in cells for k in grid.get(c, [])}
            if any(placed[k].distance(poly) < params.spacing_m for k in near):
                continue
            for c in cells:
                grid.setdefault(c, []).append(len(placed))
            placed.append(poly)
            if not poly.exterior.is_ccw:
                rect = rect[::-1]
            buildings.append(Building(f"bldg{len(buildings)}", rect, round(height, 2)))
    return buildings


def write_buildings(path: str | Path, buildings: Sequence[Building]) -> None:
    """Write buildings as a SUMO additional file of polygons (atomically)."""
    lines = ['<?xml version="1.0" encoding="UTF-8"?>', "<additional>"]
    for b in buildings:
        shape = " ".join(f"{x:.2f},{y:.2f}" for x, y in b.footprint_xy)
        lines.append(
            f'    <poly id="{b.building_id}" type="building" color="160,160,160" fill="1" layer="-1" shape="{shape}">'
        )
        lines.append(f'        <param key="height" value="{b.height_m:.2f}"/>')
        lines.append("    </poly>")
    lines.append("</additional>")
    write_text_atomic(path, "\n".join(lines) + "\n")


def read_buildings(path: str | Path) -> list[Building]:
    """Read ``<poly type="building">`` polygons (height from ``param height``, default 10 m)."""
    p = Path(path)
    try:
        root = ET.parse(p).getroot()
    except (ET.ParseError, OSError) as exc:
        raise InputError(f"{p}: not a readable SUMO polygon file ({exc}); rebuild it with 'asg towns build'") from None
    out = []
    for poly in root.iter("poly"):
        if poly.get("type") != "building":
            continue
        try:
            xy = np.asarray([[float(v) for v in pt.split(",")[:2]] for pt in poly.get("shape", "").split()], dtype=float)
        except ValueError:
            raise InputError(f"{p}: polygon {poly.get('id')!r} has a shape that is not x,y numbers; "
                             "rebuild it with 'asg towns build'") from None
        if xy.ndim != 2 or xy.shape[1] != 2 or not np.isfinite(xy).all():
            raise InputError(f"{p}: polygon {poly.get('id')!r} has a shape that is not finite x,y pairs; "
                             "rebuild it with 'asg towns build'")
        if len(xy) >= 2 and np.allclose(xy[0], xy[-1]):
            xy = xy[:-1]
        if len(xy) < 3:
            continue
        height = 10.0
        for prm in poly.iter("param"):
            if prm.get("key") == "height":
                height = parse_height_m(prm.get("value")) or height
        out.append(Building(poly.get("id"), xy, height))
    return out


def parse_height_m(text: str | None, scale: float = 1.0) -> float | None:
    """A height in metres written as OSM and SUMO files write it ("21.5", "21.5 m", "21.5m"),
    times ``scale``; None for anything else ("tall", "", NaN, or not in (0, 1000) m)."""
    text = (text or "").strip().removesuffix("m").strip()
    try:
        value = float(text) * scale
    except ValueError:
        return None
    return value if math.isfinite(value) and 0.0 < value < 1000.0 else None
