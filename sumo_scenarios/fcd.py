"""Traffic logs in SUMO's fcd-output format (gzipped XML): read and write.

SUMO reports a vehicle's position at the centre of its *front bumper*, its ``angle`` in degrees
clockwise from north (navigation convention). :func:`yaw_rad_from_sumo_angle` and
:func:`center_from_front` convert to the yaw (rad, counter-clockwise from +x) and box centre
that the rest of the project uses.
"""
from __future__ import annotations

import gzip
import math
import xml.etree.ElementTree as ET
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Iterator

from .atomic import atomic_path
from .errors import InputError
from .geometry import wrap_rad


#: the fcd-output attributes (besides ``id``) ``asg simulate`` asks SUMO for on a flat net, in SUMO's
#: order: what the reader uses. SUMO's default set adds ``pos`` and ``slope``; formatting every
#: attribute of every vehicle in every recorded frame is what the log costs in wall time
#: (docs/logs-and-scenes.md). A net with elevation adds :data:`FCD_ELEVATION_ATTRIBUTES`.
FCD_ATTRIBUTES = ("x", "y", "angle", "type", "speed", "lane")
FCD_ELEVATION_ATTRIBUTES = ("z", "slope")


@dataclass(frozen=True)
class FcdVehicle:
    """One vehicle in one time step, as SUMO writes it (front-bumper position, SUMO angle)."""

    vehicle_id: str
    x_m: float
    y_m: float
    z_m: float
    angle_deg: float
    type_id: str
    speed_mps: float
    lane_id: str
    slope_deg: float = 0.0


@dataclass(frozen=True)
class FcdFrame:
    time_s: float
    vehicles: tuple[FcdVehicle, ...]


def yaw_rad_from_sumo_angle(angle_deg: float) -> float:
    """SUMO angle (deg, clockwise from north) → yaw (rad, counter-clockwise from +x), in (-pi, pi]."""
    return wrap_rad(math.radians(90.0 - angle_deg))


def sumo_angle_from_yaw_rad(yaw_rad: float) -> float:
    """Inverse of :func:`yaw_rad_from_sumo_angle`, in [0, 360)."""
    return (90.0 - math.degrees(yaw_rad)) % 360.0


def center_from_front(x_m: float, y_m: float, yaw_rad: float, length_m: float) -> tuple[float, float]:
    """Front-bumper position → box centre, half a length back along the heading."""
    return x_m - 0.5 * length_m * math.cos(yaw_rad), y_m - 0.5 * length_m * math.sin(yaw_rad)


def front_from_center(x_m: float, y_m: float, yaw_rad: float, length_m: float) -> tuple[float, float]:
    return x_m + 0.5 * length_m * math.cos(yaw_rad), y_m + 0.5 * length_m * math.sin(yaw_rad)


def read_fcd(path: str | Path) -> Iterator[FcdFrame]:
    """Yield the frames of an fcd-output log (``.xml`` or ``.xml.gz``) in time order.

    A missing, truncated or foreign file raises InputError naming it.
    """
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: traffic log not found; run 'asg simulate' first or check the path")
    opener = gzip.open if p.name.endswith(".gz") else open
    try:
        with opener(p, "rb") as fh:
            context = ET.iterparse(fh, events=("start", "end"))
            _, root = next(context)
            if root.tag != "fcd-export":
                raise InputError(f"{p}: not an fcd-output log (root <{root.tag}>); give SUMO fcd-output")
            for event, elem in context:
                if event == "end" and elem.tag == "timestep":
                    yield FcdFrame(float(elem.get("time")), tuple(_vehicle(v) for v in elem.iter("vehicle")))
                    root.clear()
    except (ET.ParseError, EOFError, zlib.error, gzip.BadGzipFile, StopIteration) as exc:
        raise InputError(f"{p}: traffic log is truncated or corrupt ({type(exc).__name__}); re-run 'asg simulate'") from None


def _vehicle(v: ET.Element) -> FcdVehicle:
    return FcdVehicle(
        vehicle_id=v.get("id"),
        x_m=float(v.get("x")),
        y_m=float(v.get("y")),
        z_m=float(v.get("z", 0.0)),
        angle_deg=float(v.get("angle", 0.0)),
        type_id=v.get("type", ""),
        speed_mps=float(v.get("speed", 0.0)),
        lane_id=v.get("lane", ""),
        slope_deg=float(v.get("slope", 0.0)),
    )


def write_fcd(path: str | Path, frames: Iterable[FcdFrame]) -> None:
    """Write frames as a gzipped fcd-output log, atomically, in SUMO's layout and attribute order:
    :data:`FCD_ATTRIBUTES`, and ``z``/``slope`` too when any vehicle has a non-zero one."""
    frames = list(frames)
    elevated = any(v.z_m != 0.0 or v.slope_deg != 0.0 for f in frames for v in f.vehicles)
    with atomic_path(path) as tmp:
        with gzip.open(tmp, "wt", encoding="utf-8") as out:
            out.write('<?xml version="1.0" encoding="UTF-8"?>\n')
            out.write('<fcd-export xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance" '
                      'xsi:noNamespaceSchemaLocation="http://sumo.dlr.de/xsd/fcd_file.xsd">\n')
            for frame in frames:
                out.write(f'    <timestep time="{frame.time_s:.2f}">\n')
                for v in frame.vehicles:
                    z = f' z="{v.z_m:.2f}"' if elevated else ""
                    slope = f' slope="{v.slope_deg:.2f}"' if elevated else ""
                    out.write(
                        f'        <vehicle id="{v.vehicle_id}" x="{v.x_m:.2f}" y="{v.y_m:.2f}"{z} '
                        f'angle="{v.angle_deg:.2f}" type="{v.type_id}" speed="{v.speed_mps:.2f}" '
                        f'lane="{v.lane_id}"{slope}/>\n'
                    )
                out.write("    </timestep>\n")
            out.write("</fcd-export>\n")
