"""A traffic-log folder: the fcd log, its metadata, and the map it ran on, self-contained.

Layout written by ``asg simulate``::

    DIR/fcd.xml.gz          SUMO fcd-output (gzipped), front-bumper positions
    DIR/meta.yaml           this module's LogMeta: source, town, seed, vehicle types, RSUs, stats
    DIR/map.net.xml         a copy of the SUMO net (SUMO source) ...
    DIR/lanes.json.gz       ... or the lane geometry (highway-env source)
    DIR/buildings.poly.xml  buildings as SUMO polygons
"""
from __future__ import annotations

import gzip
import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal, get_args

import numpy as np
import yaml

from . import checks
from .atomic import atomic_path, write_text_atomic
from .buildings import Building, read_buildings
from .errors import InputError
from .fcd import FcdFrame, center_from_front, read_fcd, yaw_rad_from_sumo_angle
from .lanes import LaneMap
from .rsu import RoadsideUnit
from .strict import from_mapping, read_yaml

FCD_NAME = "fcd.xml.gz"
META_NAME = "meta.yaml"
NET_NAME = "map.net.xml"
LANES_NAME = "lanes.json.gz"
BUILDINGS_NAME = "buildings.poly.xml"
ROUTES_NAME = "routes.rou.xml"
VTYPES_NAME = "vtypes.add.xml"
#: every file a log folder of either source may hold
LOG_FILES = (FCD_NAME, META_NAME, NET_NAME, LANES_NAME, BUILDINGS_NAME, ROUTES_NAME, VTYPES_NAME)

#: radius (m) within which vehicles count as "near" an RSU in the density statistics:
#: the evaluation range of the paper (x, y in [-48, 48] m)
NEAR_RADIUS_M = 48.0


#: where a traffic log comes from (``asg simulate --source``, a scene's ``source``)
Source = Literal["sumo", "highway-env"]
SOURCES: tuple[str, ...] = get_args(Source)


@dataclass(frozen=True)
class LogMeta:
    source: Source
    town: str
    seed: int
    density: str
    duration_s: float
    warmup_s: float
    step_s: float
    record_period_s: float
    map_file: str
    buildings_file: str
    vehicle_types: tuple[dict[str, Any], ...]
    rsus: tuple[dict[str, Any], ...]
    stats: dict[str, Any] = field(default_factory=dict)
    env: str | None = None
    net_source: str | None = None


def write_meta(directory: Path, meta: LogMeta) -> None:
    data = asdict(meta)
    data["vehicle_types"] = list(data["vehicle_types"])
    data["rsus"] = list(data["rsus"])
    write_text_atomic(directory / META_NAME, yaml.safe_dump(data, sort_keys=False))


def write_lanes(path: Path, lane_map: LaneMap) -> None:
    with atomic_path(path) as tmp:
        with gzip.open(tmp, "wt", encoding="utf-8") as fh:
            json.dump(lane_map.to_dict(), fh)


@dataclass(frozen=True)
class TrafficLog:
    """An opened log folder: metadata, lane map, buildings, RSUs and vehicle sizes by type."""

    directory: Path
    meta: LogMeta
    lane_map: LaneMap
    buildings: tuple[Building, ...]
    rsus: tuple[RoadsideUnit, ...]

    @property
    def fcd_path(self) -> Path:
        return self.directory / FCD_NAME

    def vehicle_size(self, type_id: str) -> tuple[float, float, float]:
        """(length, width, height) in metres of a vType; unknown types get a car's size."""
        for t in self.meta.vehicle_types:
            if t["id"] == type_id:
                return float(t["length_m"]), float(t["width_m"]), float(t["height_m"])
        return 4.6, 1.85, 1.48

    def frames(self):
        return read_fcd(self.fcd_path)


def open_log(path: str | Path) -> TrafficLog:
    """Open a log folder (or the fcd file inside one)."""
    p = Path(path)
    directory = p if p.is_dir() else p.parent
    if not (directory / META_NAME).is_file():
        raise InputError(f"{p}: not a traffic-log folder (no {META_NAME}); give the --out folder of 'asg simulate'")
    where = str(directory / META_NAME)
    meta = from_mapping(LogMeta, read_yaml(directory / META_NAME), where)
    checks.safe_id(meta.town, f"{where} town")  # it names scenes and their files
    for name in (meta.map_file, meta.buildings_file):
        checks.inside(directory, directory / name, "is not in the log folder {root}; give the --out folder of 'asg simulate'")
    _check_vehicle_types(meta.vehicle_types, where)
    map_path = directory / meta.map_file
    if map_path.name.endswith(".net.xml"):
        lane_map = LaneMap.from_sumo_net(map_path)
    else:
        try:
            with gzip.open(map_path, "rt", encoding="utf-8") as fh:
                lane_map = LaneMap.from_dict(json.load(fh))
        except (OSError, EOFError, json.JSONDecodeError, KeyError, TypeError, AttributeError) as exc:
            raise InputError(f"{map_path}: lane file unreadable ({type(exc).__name__}); re-run 'asg simulate'") from None
        except InputError as exc:
            raise InputError(f"{map_path}: {exc}") from None
    buildings = tuple(read_buildings(directory / meta.buildings_file))
    rsus = tuple(RoadsideUnit.from_dict(r, f"{where} rsus[{i}]") for i, r in enumerate(meta.rsus))
    return TrafficLog(directory, meta, lane_map, buildings, rsus)


def _check_vehicle_types(types: tuple[dict[str, Any], ...], where: str) -> None:
    """Each vType of a log's meta.yaml has an id and a size a scene can hold (checks.SIZE_LIMITS_M)."""
    for i, t in enumerate(types):
        at = f"{where} vehicle_types[{i}]"
        if not isinstance(t, dict) or "id" not in t:
            raise InputError(f"{at}: expected a mapping with id, length_m, width_m and height_m")
        for key, most in checks.SIZE_LIMITS_M.items():
            checks.number(t.get(key), f"{at} {key}", 0.0, most, lo_open=True)


def density_stats(frames: list[FcdFrame], rsus: list[RoadsideUnit], sizes: dict[str, float]) -> dict[str, Any]:
    """Vehicles within ``NEAR_RADIUS_M`` of each RSU, per frame: median and 10/90th percentiles.

    Statistics are over all (frame, RSU) pairs; ``busiest_rsu_median`` is the median for the RSU
    with the most traffic. ``sizes`` maps vType id → length (m) to move front bumpers to centres.
    """
    if not frames or not rsus:
        return {"frames": len(frames), "rsus": len(rsus)}
    rsu_xy = np.array([[r.x_m, r.y_m] for r in rsus])
    counts = np.zeros((len(frames), len(rsus)), dtype=int)
    vehicles = []
    for i, f in enumerate(frames):
        vehicles.append(len(f.vehicles))
        if not f.vehicles:
            continue
        xy = np.array([
            center_from_front(v.x_m, v.y_m, yaw_rad_from_sumo_angle(v.angle_deg), sizes.get(v.type_id, 4.6))
            for v in f.vehicles
        ])
        d = np.linalg.norm(xy[:, None, :] - rsu_xy[None, :, :], axis=2)
        counts[i] = (d <= NEAR_RADIUS_M).sum(axis=0)
    per_rsu = np.median(counts, axis=0)
    return {
        "frames": len(frames),
        "rsus": len(rsus),
        "vehicles_median": float(np.median(vehicles)),
        "near_rsu_median": float(np.median(counts)),
        "near_rsu_p10": float(np.percentile(counts, 10)),
        "near_rsu_p90": float(np.percentile(counts, 90)),
        "busiest_rsu_median": float(per_rsu.max()),
        "per_rsu_median": {r.rsu_id: float(m) for r, m in zip(rsus, per_rsu)},
    }
