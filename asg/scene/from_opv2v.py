"""Scenes from recordings in OPV2V's layout (OPV2V, V2XSet, V2V4Real): ``SCENARIO/AGENT/TIMESTAMP.{pcd,yaml}``.

One scene per scenario and timestamp, with OpenCOOD's ego (asg.sensors.opv2v's rule: the agent
folders sorted as text, a leading negative one moved to the end); every agent folder a sensing
agent with its recorded scan and LiDAR pose; every labelled vehicle (the agents' ``vehicles`` merged
by id, as OpenCOOD merges them) an agent of the scene. The scene's ``recording`` block
(asg.scene.recording) references each scan by path and sha256.

Frames: OPV2V's and V2XSet's worlds are CARLA's, left-handed (x forward, y right): y and every yaw
are mirrored, as ``asg export --format opv2v`` mirrors them on the way out (a ``lidar_pose`` is
[x, y, z, roll, yaw, pitch] in degrees; a vehicle's box centre is ``location + center``, ``extent``
half its size, ``angle`` [roll, yaw, pitch] in degrees). V2V4Real's ``lidar_pose`` is a 4 x 4 matrix
to its map, right-handed, and is read as it is. Each file is read as hostile input: yaml through a
safe loader that reads numpy's data tags (V2V4Real's) and constructs nothing else, every number
checked, every path kept inside the source folder.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Iterator

import numpy as np
import yaml

from sumo_scenarios import checks
from sumo_scenarios.errors import InputError
from sumo_scenarios.lanes import LaneMap
from sumo_scenarios.numpy_yaml import add_numpy_data, add_opencood_floats

from .agent import Agent
from .recorded_pcd import in_scene_frame, read_recorded_pcd_with_digest
from .recording import (MAX_LOWERED_M, RECORDING_SOURCE, STANDARD_SENSOR_HEIGHT_M, Handedness, RecordedLidar,
                        RecordedView, Recording, RecordingFormat, opencood_ego)
from .scan_area import scan_area
from .scan_ground import GroundPlane, ground_or_none
from .scene import Scene

#: an agent folder's name: OPV2V's vehicle ids, V2XSet's negative RSU ids
_AGENT = re.compile(r"-?[0-9]{1,9}")
#: a timestamp's stem
_STAMP = re.compile(r"[0-9]{1,9}")
#: a map's lanes kept around the ego (m): what a move within the evaluation range can reach
MAP_RADIUS_M = 150.0
#: a map must carry at least this share of a recording's labelled vehicles on its roads
MAP_COVERAGE = 0.5
#: a frame yaml larger than this is not one (OPV2V's: a few kB; with camera data up to ~100 kB)
MAX_FRAME_YAML_BYTES = 2 << 20
#: a scenario folder's LiDAR description (OpenCDA's), read where present
PROTOCOL_NAME = "data_protocol.yaml"
#: the file asg's export writes beside a scenario's agent folders (ids, the lowered frames)
EXPORT_IDS_NAME = "ids.yaml"
KMH_PER_MPS = 3.6
#: the size of a sensing vehicle no agent labels (OPV2V's ego cars are about this): l, w, h (m)
UNLABELLED_CAR_M = (4.9, 2.1, 1.5)
#: the vehicle classes asg has meshes of (asg.sensors.meshes); a label's ``obj_type`` (asg's export,
#: V2V4Real's) of another class is a car
VEHICLE_TYPES = ("car", "suv", "van", "truck", "bus")
#: the pole of an RSU whose ground the scan does not show (m)
RSU_POLE_M = 4.5


class FrameLoader(getattr(yaml, "CSafeLoader", yaml.SafeLoader)):  # type: ignore[misc, valid-type]
    """Safe YAML (libyaml's parser where installed) with OpenCOOD's float rule (``1e-05`` is a number,
    as OpenCOOD's ``load_yaml`` reads a frame) and numpy's data tags read as lists and numbers
    (V2V4Real's poses); a key written twice in one mapping (two boxes under one vehicle id) refused."""

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            seen = set()
            for key_node, _ in node.value:
                if isinstance(key_node, yaml.ScalarNode):
                    if key_node.value in seen:
                        line = key_node.start_mark.line + 1
                        raise yaml.constructor.ConstructorError(
                            None, None, f"id or key {key_node.value[:40]!r} written twice (line {line})", key_node.start_mark)
                    seen.add(key_node.value)
        return super().construct_mapping(node, deep)


add_numpy_data(add_opencood_floats(FrameLoader))


@dataclass(frozen=True)
class ImportParams:
    """Which timestamps become scenes: every ``every``-th of each scenario, at most ``limit`` in all;
    ``map``: the recording's town (an OpenDRIVE .xodr, e.g. the CARLA town's, or a SUMO net) whose
    lanes become each scene's, instead of the drivable area read from the scans."""
    every: int = 1
    limit: int | None = None
    map: Path | None = None

    def validate(self) -> "ImportParams":
        checks.number(self.every, "--every", 1, 1_000_000)
        if self.limit is not None:
            checks.number(self.limit, "--limit", 1, 10_000_000)
        return self


def scenario_folders(source: Path) -> list[Path]:
    """``source`` itself if it is a scenario folder (agent folders inside), else its sub-folders that
    are (a split); InputError if none is, or a folder leaves ``source`` through a link."""
    source = Path(source)
    if not source.is_dir():
        raise InputError(f"{source}: not a folder; give an OPV2V scenario folder or a split of them")
    if _agent_dirs(source, source):
        return [source]
    found = [p for p in sorted(source.iterdir()) if p.is_dir() and _agent_dirs(p, source)]
    if not found:
        raise InputError(f"{source}: holds no OPV2V scenario (a folder of agent folders named by integer ids, "
                         "each with TIMESTAMP.yaml and TIMESTAMP.pcd)")
    return found


def _agent_dirs(folder: Path, root: Path) -> list[Path]:
    dirs = [p for p in sorted(folder.iterdir()) if p.is_dir() and _AGENT.fullmatch(p.name)]
    for p in dirs:
        _within(root, p)
    numbers = [int(p.name) for p in dirs]
    twice = next((p.name for p, n in zip(dirs, numbers) if numbers.count(n) > 1), None)
    if twice is not None:
        raise InputError(f"{folder}: two agent folders name agent {int(twice)} ({twice} and another); "
                         "OpenCOOD reads one")
    return dirs


def _within(root: Path, path: Path) -> Path:
    """``path``, refused unless it resolves inside the source folder ``root`` (a link out of it)."""
    return checks.inside(root, path, "leads outside {root} (a link); a recording's files must lie inside the folder imported")


def import_scenes(source: Path, params: ImportParams = ImportParams()) -> Iterator[Scene]:
    """The scenes of every scenario of ``source`` (see the module docstring), in scenario and
    timestamp order."""
    from sumo_scenarios.town_import import map_lanes

    params.validate()
    source = Path(source).resolve()
    folders = scenario_folders(source)
    lanes = map_lanes(params.map) if params.map is not None else None
    made = 0
    for scenario in folders:
        for stamp in _timestamps(scenario, source)[::params.every]:
            if params.limit is not None and made >= params.limit:
                return
            yield _scene(scenario, stamp, source, lanes, params.map)
            made += 1


def planned_count(source: Path, params: ImportParams = ImportParams()) -> int:
    """How many scenes :func:`import_scenes` will yield (its folders listed, no file read)."""
    params.validate()
    source = Path(source).resolve()
    total = sum(len(_timestamps(s, source)[::params.every]) for s in scenario_folders(source))
    return total if params.limit is None else min(total, params.limit)


def _timestamps(scenario: Path, root: Path) -> list[str]:
    """The timestamps every agent folder of ``scenario`` holds (yaml and pcd); InputError where the
    folders disagree (OpenCOOD reads the same timestamps from each) or a file is missing."""
    stamps = {}
    for agent in _agent_dirs(scenario, root):
        yamls = {p.stem for p in agent.glob("*.yaml") if _STAMP.fullmatch(p.stem)}
        pcds = {p.stem for p in agent.glob("*.pcd") if _STAMP.fullmatch(p.stem)}
        if yamls != pcds:
            odd = sorted(yamls ^ pcds)[0]
            raise InputError(f"{agent}: timestamp {odd} has a yaml without a pcd or a pcd without a yaml")
        stamps[agent.name] = yamls
    first = next(iter(stamps.values()))
    differ = next((a for a, s in stamps.items() if s != first), None)
    if differ is not None:
        raise InputError(f"{scenario}: agent folder {differ} holds other timestamps than the others; every agent "
                         "folder of a scenario holds the same ones")
    if not first:
        raise InputError(f"{scenario}: its agent folders hold no TIMESTAMP.yaml and TIMESTAMP.pcd")
    return sorted(first, key=lambda s: (int(s), s))


def read_frame_yaml(path: Path) -> dict:
    """One agent's frame yaml as data; InputError (one line) for a missing, oversized, malformed
    file, a Python tag other than numpy's data, or no mapping."""
    try:
        if path.stat().st_size > MAX_FRAME_YAML_BYTES:
            raise InputError(f"{path}: over {MAX_FRAME_YAML_BYTES} bytes; not a frame's yaml")
        data = yaml.load(path.read_text(encoding="utf-8"), Loader=FrameLoader)
    except OSError as exc:
        raise InputError(f"{path}: cannot be read ({exc.strerror})") from None
    except yaml.constructor.ConstructorError as exc:
        raise InputError(f"{path}: {exc.problem}") from None
    except (yaml.YAMLError, UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise InputError(f"{path}: not a readable frame yaml ({type(exc).__name__})") from None
    if not isinstance(data, dict):
        raise InputError(f"{path}: expected a mapping (lidar_pose, vehicles, ...)")
    return data


def _scene(scenario: Path, stamp: str, root: Path, lanes: LaneMap | None = None, map_path: Path | None = None) -> Scene:
    agents = [p.name for p in _agent_dirs(scenario, root)]
    metas = {a: read_frame_yaml(_within(root, scenario / a / f"{stamp}.yaml")) for a in agents}
    handed = _handedness(metas, scenario / agents[0] / f"{stamp}.yaml")
    views, clouds = {}, {}
    lowered = _lowered_frames(scenario, root)
    for a in agents:
        pcd = _within(root, scenario / a / f"{stamp}.pcd").resolve()
        where = scenario / a / f"{stamp}.yaml"
        pose, roll, pitch = _lidar_pose(metas[a].get("lidar_pose"), handed, where)
        raw, sha256 = read_recorded_pcd_with_digest(pcd)
        views[a] = RecordedView(str(pcd), sha256, len(raw), pose, roll, pitch, lowered.get(a, 0.0))
        clouds[a] = in_scene_frame(raw, handed)
    vehicles = _labelled(metas, handed, scenario, stamp)
    planes = {a: ground_or_none(clouds[a]) for a in agents}  # fitted once: the agents' ground, the area
    sensing = _sensing_agents(agents, metas, vehicles, views, planes)
    all_agents = tuple(vehicles.values()) + tuple(a for a in sensing if a.agent_id not in vehicles)
    ego = opencood_ego(agents)
    scene_id = checks.safe_id(f"{_safe_stem(scenario.name)}-{stamp}", "scene id")
    recording = Recording(RecordingFormat.OPV2V, handed, str(scenario), stamp, _lidar_of(scenario, root), views,
                          tuple(a for a in all_agents if a.is_vehicle))  # as recorded: the unlabelled sensing cars too
    scene = Scene(scene_id=scene_id, town=_safe_stem(scenario.name), source=RECORDING_SOURCE,
                  time_s=int(stamp) * 0.05, ego_id=ego, agents=all_agents, buildings=(), lane_map=LaneMap([]),
                  collaborators=tuple(a for a in agents if a != ego), log=str(scenario), recording=recording)
    if lanes is None:
        return replace(scene, lane_map=scan_area(scene, clouds, planes))
    x, y = views[ego].sensor[:2]
    town = map_path.name.split(".")[0]  # the map's town (a bundled or imported town's net: what exports read)
    return replace(scene, town=_safe_stem(town),
                   lane_map=_covering(lanes.crop((x, y), MAP_RADIUS_M), vehicles, scene.scene_id, map_path))


def _covering(lanes: LaneMap, vehicles: dict[str, Agent], scene_id: str, map_path: Path | None) -> LaneMap:
    """``lanes`` if they carry the recording's labelled vehicles (at least MAP_COVERAGE of them stand
    on the drivable area); InputError for a map that does not cover, or is not aligned with, it."""
    if not vehicles:
        return lanes
    on = sum(lanes.point_on_road(a.x_m, a.y_m) for a in vehicles.values())
    if not lanes.lanes or on < MAP_COVERAGE * len(vehicles):
        raise InputError(f"{map_path}: {on} of the {len(vehicles)} labelled vehicles of {scene_id} stand on its roads; "
                         "the map does not cover the recording (give its own town's map)")
    return lanes


def _lowered_frames(scenario: Path, root: Path) -> dict[str, float]:
    """{agent folder: how far its view's frame lies below its LiDAR (m)}: asg's export writes a high
    sensor's view in a lowered frame and records it in the scenario's ids.yaml (``frames_lowered_m``);
    a recording without that file has its LiDAR at each frame's origin."""
    path = scenario / EXPORT_IDS_NAME
    if not path.is_file():
        return {}
    lowered = read_frame_yaml(_within(root, path)).get("frames_lowered_m") or {}
    if not isinstance(lowered, dict):
        raise InputError(f"{path}: frames_lowered_m must map agent ids to metres")
    return {str(k): checks.number(v, f"{path}: frames_lowered_m", 0.0, MAX_LOWERED_M) for k, v in lowered.items()}


def _safe_stem(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name)[:80].strip("._-") or "scenario"


def _handedness(metas: dict, where: Path) -> Handedness:
    """Left (CARLA: a 6-value lidar_pose) or right (V2V4Real: a 4 x 4 matrix), one for the frame."""
    kinds = {len(m["lidar_pose"]) if isinstance(m.get("lidar_pose"), list) else -1 for m in metas.values()}
    if kinds == {6}:
        return Handedness.LEFT
    if kinds == {4}:
        return Handedness.RIGHT
    raise InputError(f"{where}: lidar_pose must be [x, y, z, roll, yaw, pitch] (OPV2V) or a 4 x 4 matrix "
                     "(V2V4Real), the same in every agent's file")


def _finite_list(value, n: int, where: str) -> list[float]:
    if not isinstance(value, list) or len(value) != n:
        raise InputError(f"{where}: expected a list of {n} numbers")
    return [checks.number(v, where, -1.0e6, 1.0e6) for v in value]


def _lidar_pose(value, handed: Handedness, where: Path) -> tuple[tuple[float, float, float, float], float, float]:
    """((x_m, y_m, z_m, yaw_rad) in the scene's frame, roll_deg, pitch_deg) of a lidar_pose."""
    if handed is Handedness.LEFT:
        x, y, z, roll, yaw, pitch = _finite_list(value, 6, f"{where}: lidar_pose")
        return (x, -y, z, -math.radians(yaw)), -roll, pitch  # mirrored in y: roll and yaw turn, pitch stays
    rows = [_finite_list(r, 4, f"{where}: lidar_pose") for r in (value if isinstance(value, list) else [None])]
    m = np.asarray(rows, dtype=float)
    if m.shape != (4, 4) or not np.allclose(m[3], [0, 0, 0, 1]) or not np.allclose(m[:3, :3] @ m[:3, :3].T, np.eye(3), atol=1e-3):
        raise InputError(f"{where}: lidar_pose is not a rigid 4 x 4 transform")
    yaw = math.atan2(m[1, 0], m[0, 0])
    pitch = math.degrees(math.asin(max(-1.0, min(1.0, -m[2, 0]))))
    roll = math.degrees(math.atan2(m[2, 1], m[2, 2]))
    return (float(m[0, 3]), float(m[1, 3]), float(m[2, 3]), yaw), roll, pitch


def _labelled(metas: dict, handed: Handedness, scenario: Path, stamp: str) -> dict[str, Agent]:
    """Every labelled vehicle by id (the agents' lists merged in folder order, a later one winning,
    as OpenCOOD merges them)."""
    out: dict[str, Agent] = {}
    for a, meta in metas.items():
        listed = meta.get("vehicles") or {}
        where = scenario / a / f"{stamp}.yaml"
        if not isinstance(listed, dict):
            raise InputError(f"{where}: vehicles must map ids to boxes")
        for vid, box in listed.items():
            vid = checks.safe_id(str(vid), f"{where}: vehicle id")
            out[vid] = _vehicle(vid, box, handed, f"{where}: vehicle {vid}")
    return out


def _vehicle(vid: str, box, handed: Handedness, where: str) -> Agent:
    if not isinstance(box, dict):
        raise InputError(f"{where}: expected location, center, extent and angle")
    try:
        loc, center, extent, angle = (box[k] for k in ("location", "center", "extent", "angle"))
    except KeyError as exc:
        raise InputError(f"{where}: lacks {exc.args[0]}") from None
    lx, ly, lz = _finite_list(loc, 3, f"{where} location")
    cx, cy, cz = _finite_list(center, 3, f"{where} center")
    ex, ey, ez = _finite_list(extent, 3, f"{where} extent")
    _, yaw_deg, _ = _finite_list(angle, 3, f"{where} angle")
    sign = -1.0 if handed is Handedness.LEFT else 1.0
    size = {"length_m": 2 * ex, "width_m": 2 * ey, "height_m": 2 * ez}
    for key, v in size.items():
        checks.number(v, f"{where} {key}", 0.0, checks.SIZE_LIMITS_M[key], lo_open=True)
    speed = checks.number(box.get("speed", 0.0), f"{where} speed", -1000.0, 1000.0)
    kind = str(box.get("obj_type", "car")).lower()
    return Agent(agent_id=vid, kind="vehicle", type_id=kind if kind in VEHICLE_TYPES else "car",
                 x_m=lx + cx, y_m=sign * (ly + cy), z_m=lz + cz - ez, yaw_rad=sign * math.radians(yaw_deg),
                 speed_mps=min(abs(speed) / KMH_PER_MPS, 150.0), **size)


def _sensing_agents(agents: list[str], metas: dict, vehicles: dict[str, Agent], views: dict,
                    planes: dict[str, GroundPlane | None]) -> list[Agent]:
    """Each agent folder as an agent: the labelled vehicle of its id, else an RSU (a negative id or
    ``RSU: true``) or a vehicle of UNLABELLED_CAR_M below its LiDAR, on the ground its scan shows
    (``planes``: each agent's, in its file's frame; None where its scan shows no road), or for a view
    asg's export wrote in a lowered frame, on the ground that frame was put above (exactly
    STANDARD_SENSOR_HEIGHT_M below it: an export of the imported scene lowers it by the same again)."""
    out = []
    for a in agents:
        if a in vehicles:
            out.append(vehicles[a])
            continue
        x, y, z, yaw = views[a].sensor
        lidar_z = views[a].lidar_pose[2]
        if views[a].origin_z_m:
            ground_z = z - STANDARD_SENSOR_HEIGHT_M
        else:
            ground_z = None if planes[a] is None else z + planes[a].c
        if int(a) < 0 or metas[a].get("RSU") is True:
            ground = lidar_z - RSU_POLE_M if ground_z is None else ground_z
            out.append(Agent(a, "rsu", "rsu", x, y, ground, yaw, 0.4, 0.4, max(lidar_z - ground, 0.5)))
        else:
            length, width, height = UNLABELLED_CAR_M
            ground = lidar_z - STANDARD_SENSOR_HEIGHT_M if ground_z is None else ground_z
            out.append(Agent(a, "vehicle", "car", x, y, ground, yaw, length, width, height))
    return out


def _lidar_of(scenario: Path, root: Path) -> RecordedLidar:
    """The scenario's LiDAR from its data_protocol.yaml (the first mapping holding CARLA's lidar
    attributes), else OPV2V's (RecordedLidar's defaults)."""
    path = scenario / PROTOCOL_NAME
    if not path.is_file():
        return RecordedLidar()
    found = _lidar_block(read_frame_yaml(_within(root, path)))
    if found is None:
        return RecordedLidar()
    d = RecordedLidar().to_dict()
    names = {"channels": "channels", "upper_fov": "upper_deg", "lower_fov": "lower_deg", "range": "range_m",
             "points_per_second": "points_per_s", "rotation_frequency": "rotation_hz"}
    d.update({ours: found[theirs] for theirs, ours in names.items() if theirs in found})
    return RecordedLidar.from_dict(d, str(path))


def _lidar_block(value, depth: int = 0):
    if depth > 12:
        return None
    if isinstance(value, dict):
        if "channels" in value and ("upper_fov" in value or "points_per_second" in value):
            return value
        for v in value.values():
            if (found := _lidar_block(v, depth + 1)) is not None:
                return found
    return None
