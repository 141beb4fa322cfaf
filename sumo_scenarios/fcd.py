"""Traffic logs in SUMO's fcd-output format (gzipped XML): read and write.

SUMO reports a vehicle's position at the centre of its *front bumper*, its ``angle`` in degrees
clockwise from north (navigation convention). :func:`yaw_rad_from_sumo_angle` and
:func:`center_from_front` convert to the yaw (rad, counter-clockwise from +x) and box centre
that the rest of the project uses.

A log is a file a user hands in: every vehicle needs a safe id (it may become a file name) and
numbers that are finite and in range; one that has not is refused in one line naming it.
"""
from __future__ import annotations

import gzip
import math
import xml.etree.ElementTree as ET
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Iterator

from .atomic import atomic_path
from .checks import MAX_ABS_Z_M, MAX_COORD_M, MAX_SPEED_MPS, is_label, is_safe_id
from .errors import InputError
from .geometry import wrap_rad


#: the fcd-output attributes (besides ``id``) ``asg simulate`` asks SUMO for on a flat net, in SUMO's
#: order: what the reader uses. SUMO's default set adds ``pos`` and ``slope``; formatting every
#: attribute of every vehicle in every recorded frame is what the log costs in wall time
#: (docs/logs-and-scenes.md). A net with elevation adds :data:`FCD_ELEVATION_ATTRIBUTES`.
FCD_ATTRIBUTES = ("x", "y", "angle", "type", "speed", "lane")
FCD_ELEVATION_ATTRIBUTES = ("z", "slope")
#: a vehicle's numbers in a log: (attribute, its value when absent (None: required), lowest, highest).
#: SUMO writes angles in [0, 360) and slopes in [-90, 90] degrees
_NUMBERS = (("x", None, -MAX_COORD_M, MAX_COORD_M), ("y", None, -MAX_COORD_M, MAX_COORD_M),
            ("z", 0.0, -MAX_ABS_Z_M, MAX_ABS_Z_M), ("angle", 0.0, -360.0, 720.0),
            ("speed", 0.0, -MAX_SPEED_MPS, MAX_SPEED_MPS), ("slope", 0.0, -90.0, 90.0))
_ATTRIBUTES = tuple((name, default) for name, default, _, _ in _NUMBERS)
_LO, _HI = tuple(n[2] for n in _NUMBERS), tuple(n[3] for n in _NUMBERS)
#: the latest time step a log may hold (s): a year
MAX_TIME_S = 3.2e7


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

    A missing, truncated or foreign file, and a vehicle with an unsafe id or a number that is
    missing, not finite or out of range (``_NUMBERS``), raise InputError naming it.
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
            checked = _Checked()  # ids and types already checked (a vehicle stays in many frames)
            for event, elem in context:
                if event == "end" and elem.tag == "timestep":
                    yield _frame(elem, p, checked)
                    root.clear()
    except (ET.ParseError, EOFError, zlib.error, gzip.BadGzipFile, StopIteration) as exc:
        raise InputError(f"{p}: traffic log is truncated or corrupt ({type(exc).__name__}); re-run 'asg simulate'") from None


def _frame(elem: ET.Element, path: Path, checked: "_Checked") -> FcdFrame:
    """One ``<timestep>``; InputError naming the file, the time and the first vehicle it refuses."""
    try:
        time_s = float(elem.get("time"))
    except (TypeError, ValueError):
        time_s = math.nan
    if not -MAX_TIME_S <= time_s <= MAX_TIME_S:
        raise InputError(f"{path}: a timestep's time {str(elem.get('time'))[:30]!r} is not a time in seconds; "
                         "give a log written by SUMO's fcd-output ('asg simulate')")
    vehicles = []
    for v in elem.iter("vehicle"):
        try:
            vehicles.append(_vehicle(v, checked))
        except (TypeError, ValueError):
            raise InputError(f"{path}: at time {time_s:g}: {_problem(v)}; fix the log or re-run 'asg simulate'") from None
    return FcdFrame(time_s, tuple(vehicles))


@dataclass
class _Checked:
    """The vehicle ids and types a log's reader has accepted so far."""

    ids: set[str] = field(default_factory=set)
    types: set[str] = field(default_factory=set)


def _vehicle(v: ET.Element, checked: _Checked) -> FcdVehicle:
    """One ``<vehicle>``; TypeError or ValueError if :func:`_problem` finds something wrong."""
    get = v.get
    x, y, z, angle, speed, slope = [float(get(name, default)) for name, default in _ATTRIBUTES]  # None: TypeError
    if not (_LO[0] <= x <= _HI[0] and _LO[1] <= y <= _HI[1] and _LO[2] <= z <= _HI[2]  # NaN fails too
            and _LO[3] <= angle <= _HI[3] and _LO[4] <= speed <= _HI[4] and _LO[5] <= slope <= _HI[5]):
        raise ValueError
    vehicle_id, type_id = get("id"), get("type", "")
    if vehicle_id not in checked.ids:
        if vehicle_id is None or not is_safe_id(vehicle_id):
            raise ValueError
        checked.ids.add(vehicle_id)
    if type_id not in checked.types:
        if not is_label(type_id):
            raise ValueError
        checked.types.add(type_id)
    return FcdVehicle(vehicle_id, x, y, z, angle, type_id, speed, get("lane", ""), slope)


def _problem(v: ET.Element) -> str:
    """What is wrong with a ``<vehicle>`` that :func:`_vehicle` refused, in words."""
    vehicle_id = v.get("id")
    if vehicle_id is None:
        return "a vehicle without an id"
    where = f"vehicle {vehicle_id[:40]!r}"
    if not is_safe_id(vehicle_id):
        return f"{where}: its id is not a safe name (letters, digits and _ - . # : + only, at most 128)"
    if not is_label(v.get("type", "")):
        return f"{where}: its type {v.get('type')[:40]!r} is not a type name (no spaces or | \\ ' \" ; , < > &)"
    for name, default, lo, hi in _NUMBERS:
        text = v.get(name)
        if text is None:
            if default is None:
                return f"{where}: no {name}"
            continue
        try:
            value = float(text)
        except ValueError:
            return f"{where}: {name} {text[:30]!r} is not a number"
        if not math.isfinite(value):
            return f"{where}: {name} {value} is not a finite number"
        if not lo <= value <= hi:
            return f"{where}: {name} {value:g} is out of range ({lo:g} to {hi:g})"
    return f"{where}: unreadable"


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
