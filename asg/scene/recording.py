"""A recorded frame behind a scene (``source: recording``): where each sensing agent's recorded cloud
is, what its LiDAR's pose was, and every labelled vehicle as recorded.

A scene imported from a recording in OPV2V's layout (asg.scene.from_opv2v) keeps its agents as
any scene does; this block says what was *recorded*, so that a renderer can tell which vehicles a
search changed (moved, inserted, removed) and edit only those out of and into the recorded clouds
(asg.sensors.recorded). The clouds are referenced, not copied: a recording's clouds are large (OPV2V:
about 3 MB a scan, thousands of scans) and a scene folder of every timestamp would copy all of them;
each reference carries the file's sha256 and point count, checked when the cloud is read, so a
changed or swapped file is refused instead of silently rendered.

Frames: every pose here is in the scene's frame (right-handed: x east, y north, z up; the import
mirrors CARLA's left-handed y), yaw in radians; a sensor's roll and pitch are recorded (degrees) but
the renderer's sensor frames have yaw only.

Schema (the scene's ``recording`` key)::

    format: opv2v            # the layout it was read from (RecordingFormat)
    handed: left | right     # CARLA's left-handed clouds (mirrored on reading) or right-handed ones
    scenario: /abs/path      # the scenario folder
    timestamp: "000069"
    lidar: {channels, upper_deg, lower_deg, points_per_s, rotation_hz, range_m}   # the recorded LiDAR
    views: {AGENT_ID: {cloud: /abs/path.pcd, sha256, points, sensor: [x_m, y_m, z_m, yaw_rad],
                       roll_deg, pitch_deg, origin_z_m}}
    vehicles: [Agent]        # every labelled vehicle as recorded (scene agent schema)
"""
from __future__ import annotations

import enum
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping

from sumo_scenarios import checks
from sumo_scenarios.errors import InputError

from .agent import MAX_ABS_YAW_RAD, Agent

#: a scene's source when its frame is a recording (beside the traffic sources of sumo_scenarios.log)
RECORDING_SOURCE = "recording"
_SHA256 = re.compile(r"[0-9a-f]{64}")
#: the furthest a view's frame may lie below its LiDAR (m; asg's export lowers a 4.5 m RSU by 2.6)
MAX_LOWERED_M = 20.0
#: the height above the ground of OPV2V's vehicle LiDAR (m): the frame asg's export writes a high
#: sensor's view in (asg.sensors.ego_frame), so a lowered view's ground lies this far below its frame
STANDARD_SENSOR_HEIGHT_M = 1.9
#: the most points one recorded cloud may hold (OPV2V: about 60k; a 128-channel scan: about 250k)
MAX_CLOUD_POINTS = 4_000_000


def opencood_ego(folders: list[str]) -> str:
    """The agent folder OpenCOOD's OPV2V / V2XSet loaders take as the ego: the folder names sorted
    as strings, a leading negative (RSU) one moved to the end, then the first
    (asg.sensors.opv2v.opv2v_ids numbers an export's folders so that this is always its ego)."""
    order = sorted(folders)
    if order and int(order[0]) < 0:
        order = order[1:] + order[:1]
    return order[0]


class RecordingFormat(str, enum.Enum):
    """The layouts a recording is imported from (``asg scenes import --format``)."""
    OPV2V = "opv2v"  # OPV2V, V2XSet, V2V4Real: split/SCENARIO/AGENT/TIMESTAMP.{pcd,yaml}


class Handedness(str, enum.Enum):
    """How a recording's clouds and poses are handed: CARLA's worlds (OPV2V, V2XSet) are left-handed
    (y right) and are mirrored on reading; real vehicles' (V2V4Real) right-handed."""
    LEFT = "left"
    RIGHT = "right"


@dataclass(frozen=True)
class RecordedLidar:
    """The recorded LiDAR (a scenario's data_protocol.yaml, else OPV2V's): ``channels`` rings from
    ``upper_deg`` down to ``lower_deg``, ``points_per_s`` at ``rotation_hz``, ``range_m``; its beam
    pattern gives the rays of the directions where the scan recorded no return."""
    channels: int = 64
    upper_deg: float = 2.0
    lower_deg: float = -25.0
    points_per_s: float = 1_300_000.0
    rotation_hz: float = 20.0
    range_m: float = 120.0

    def to_dict(self) -> dict:
        return {"channels": self.channels, "upper_deg": self.upper_deg, "lower_deg": self.lower_deg,
                "points_per_s": self.points_per_s, "rotation_hz": self.rotation_hz, "range_m": self.range_m}

    @staticmethod
    def from_dict(d: Mapping, where: str = "lidar") -> "RecordedLidar":
        if not isinstance(d, Mapping):
            raise InputError(f"{where}: expected a mapping of the LiDAR's settings")
        limits = checks.LIDAR_LIMITS
        upper = checks.number(d["upper_deg"], f"{where} upper_deg", *limits["elevation_deg"])
        channels = int(checks.number(d["channels"], f"{where} channels", *limits["channels"]))
        rate = checks.number(d["points_per_s"], f"{where} points_per_s", *limits["points_per_s"])
        hz = checks.number(d["rotation_hz"], f"{where} rotation_hz", *limits["rotation_hz"])
        low, high = limits["returns_per_ring"]
        if not low <= rate / hz / channels <= high:
            raise InputError(f"{where}: {rate / hz / channels:.0f} returns a ring; points_per_s / rotation_hz / "
                             f"channels must lie in {low}..{high}")
        return RecordedLidar(channels, upper,
                             checks.number(d["lower_deg"], f"{where} lower_deg", limits["elevation_deg"][0], upper),
                             rate, hz, checks.number(d["range_m"], f"{where} range_m", *limits["range_m"]))


@dataclass(frozen=True)
class RecordedView:
    """One sensing agent's recorded scan: its cloud file (absolute), that file's sha256 and point
    count, and the pose of its view's frame in the scene's frame (x_m, y_m, z_m, yaw_rad; roll and
    pitch kept). ``origin_z_m``: how far above that frame's origin the LiDAR's rays start (0 but
    where the view was written in a lowered frame, as asg's export writes a high sensor's); the
    renderer gives the view in its LiDAR's own frame (:attr:`lidar_pose`)."""
    cloud: str
    sha256: str
    points: int
    sensor: tuple[float, float, float, float]
    roll_deg: float = 0.0
    pitch_deg: float = 0.0
    origin_z_m: float = 0.0

    @property
    def lidar_pose(self) -> tuple[float, float, float, float]:
        """(x_m, y_m, z_m, yaw_rad) of the LiDAR itself in the scene's frame: ``sensor`` raised by
        ``origin_z_m`` (the frame a native scene's frame of this agent has)."""
        x, y, z, yaw = self.sensor
        return x, y, z + self.origin_z_m, yaw

    def to_dict(self) -> dict:
        return {"cloud": self.cloud, "sha256": self.sha256, "points": self.points,
                "sensor": [float(v) for v in self.sensor], "roll_deg": float(self.roll_deg),
                "pitch_deg": float(self.pitch_deg), "origin_z_m": float(self.origin_z_m)}

    @staticmethod
    def from_dict(d: Mapping, where: str) -> "RecordedView":
        cloud = str(d["cloud"])
        if not Path(cloud).is_absolute():
            raise InputError(f"{where}: cloud {cloud[:80]!r} must be an absolute path (asg scenes import writes one)")
        sha = str(d["sha256"])
        if not _SHA256.fullmatch(sha):
            raise InputError(f"{where}: sha256 {sha[:70]!r} is not a sha256 in hex")
        sensor = d["sensor"]
        if not isinstance(sensor, list) or len(sensor) != 4:
            raise InputError(f"{where}: sensor must be [x_m, y_m, z_m, yaw_rad]")
        x, y = (checks.coordinate(v, f"{where} sensor") for v in sensor[:2])
        z = checks.number(sensor[2], f"{where} sensor z", -10_000.0, 10_000.0)
        yaw = checks.number(sensor[3], f"{where} sensor yaw", -MAX_ABS_YAW_RAD, MAX_ABS_YAW_RAD)
        return RecordedView(cloud, sha, int(checks.number(d["points"], f"{where} points", 0, MAX_CLOUD_POINTS)),
                            (x, y, z, yaw), checks.number(d.get("roll_deg", 0.0), f"{where} roll_deg", -180, 180),
                            checks.number(d.get("pitch_deg", 0.0), f"{where} pitch_deg", -180, 180),
                            checks.number(d.get("origin_z_m", 0.0), f"{where} origin_z_m", 0.0, MAX_LOWERED_M))


@dataclass(frozen=True)
class Recording:
    """What was recorded at one timestamp of one scenario (see the module docstring)."""
    format: RecordingFormat
    handed: Handedness
    scenario: str
    timestamp: str
    lidar: RecordedLidar
    views: Mapping[str, RecordedView]
    vehicles: tuple[Agent, ...] = field(default=())

    def to_dict(self) -> dict:
        return {"format": self.format.value, "handed": self.handed.value, "scenario": self.scenario,
                "timestamp": self.timestamp, "lidar": self.lidar.to_dict(),
                "views": {k: v.to_dict() for k, v in self.views.items()},
                "vehicles": [a.to_dict() for a in self.vehicles]}

    @staticmethod
    def from_dict(d, where: str = "recording") -> "Recording":
        if not isinstance(d, dict):
            raise InputError(f"{where}: 'recording' must be a mapping")
        known = {"format", "handed", "scenario", "timestamp", "lidar", "views", "vehicles"}
        unknown = sorted(str(k) for k in set(d) - known)
        if unknown:
            raise InputError(f"{where}: unknown key '{unknown[0][:40]}' in 'recording' (known: {', '.join(sorted(known))})")
        try:
            fmt, handed = RecordingFormat(d["format"]), Handedness(d["handed"])
        except ValueError:
            raise InputError(f"{where}: format must be one of {', '.join(f.value for f in RecordingFormat)} and "
                             f"handed one of {', '.join(h.value for h in Handedness)}") from None
        views = d["views"]
        if not isinstance(views, dict) or not views:
            raise InputError(f"{where}: 'views' must map each sensing agent to its recorded cloud")
        return Recording(fmt, handed, str(d["scenario"]), str(d["timestamp"]),
                         RecordedLidar.from_dict(d["lidar"], f"{where} lidar"),
                         {checks.safe_id(k, f"{where} view"): RecordedView.from_dict(v, f"{where} view {str(k)[:20]!r}")
                          for k, v in views.items()},
                         tuple(Agent.from_dict(a) for a in (d.get("vehicles") or [])))

    def recorded(self, agent_id: str) -> Agent | None:
        """The vehicle ``agent_id`` as recorded (None: not a labelled vehicle of the recording)."""
        return next((a for a in self.vehicles if a.agent_id == agent_id), None)
