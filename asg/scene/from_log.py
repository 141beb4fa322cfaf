"""Scenes from traffic logs: the one module of ``asg`` that reads them (through sumo_scenarios)."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Iterator, Literal, get_args

import numpy as np

from sumo_scenarios import checks
from sumo_scenarios.errors import InputError
from sumo_scenarios.fcd import FcdFrame, center_from_front, yaw_rad_from_sumo_angle
from sumo_scenarios.log import NEAR_RADIUS_M, TrafficLog, open_log
from sumo_scenarios.rsu import RoadsideUnit
from shapely.geometry import Point, Polygon

from .agent import Agent
from .neighbours import random_collaborators
from .scene import Scene

EgoChoice = Literal["rsu", "vehicle"]
#: the kinds of agent a scene's ego can be (``asg scenes extract --ego``)
EGO_KINDS: tuple[str, ...] = get_args(EgoChoice)


@dataclass(frozen=True)
class ExtractParams:
    """Which frames become scenes and what they hold.

    ``every``: take every N-th recorded frame; ``radius_m``: keep agents, lanes and buildings
    within this distance of the ego; ``ego``: an RSU (V2I) or a vehicle (V2V) as ego, whichever has
    the most vehicles within the evaluation range; ``min_vehicles``: skip frames with fewer vehicles
    near the ego; ``collaborators``: how many sensing vehicles to draw besides the ego.
    """

    every: int = 10
    radius_m: float = 120.0
    ego: EgoChoice = "rsu"
    min_vehicles: int = 1
    #: collaborators drawn at random among the vehicles in communication range of the ego, as the
    #: data sets draw them (0: none; the generator then picks its own)
    collaborators: int = 0
    #: frames before this time (s) are not scenes; the every-N count starts at the first one after
    from_s: float = 0.0

    def validate(self) -> None:
        if self.every < 1:
            raise InputError(f"--every must be a positive whole number, got {self.every}")
        if self.ego not in EGO_KINDS:
            raise InputError(f"--ego must be rsu or vehicle, got {self.ego!r}")
        checks.number(self.radius_m, f"--radius (m; beyond the {NEAR_RADIUS_M:g} m evaluation range)", NEAR_RADIUS_M,
                      10_000.0, lo_open=True)
        checks.number(self.collaborators, "--collaborators", 0, 16)


def frame_vehicles(log: TrafficLog, frame: FcdFrame) -> list[Agent]:
    """All vehicles of a frame as agents (box centres, yaw in rad, sizes from the log's vTypes)."""
    out = []
    for v in frame.vehicles:
        length, width, height = log.vehicle_size(v.type_id)
        yaw = yaw_rad_from_sumo_angle(v.angle_deg)
        x, y = center_from_front(v.x_m, v.y_m, yaw, length)
        out.append(Agent(v.vehicle_id, "vehicle", v.type_id, x, y, v.z_m, yaw, length, width, height,
                         v.speed_mps, v.lane_id or None))
    return out


def rsu_agent(rsu: RoadsideUnit) -> Agent:
    return Agent(rsu.rsu_id, "rsu", "rsu", rsu.x_m, rsu.y_m, 0.0, 0.0, 0.4, 0.4, rsu.height_m)


def _pick_ego(vehicles: list[Agent], rsus: list[Agent], choice: EgoChoice) -> tuple[Agent | None, int]:
    if not vehicles:
        return None, 0
    vxy = np.array([[a.x_m, a.y_m] for a in vehicles])
    candidates = rsus if choice == "rsu" else vehicles
    if not candidates:
        return None, 0
    cxy = np.array([[a.x_m, a.y_m] for a in candidates])
    near = (np.linalg.norm(cxy[:, None] - vxy[None], axis=2) <= NEAR_RADIUS_M).sum(axis=1)
    if choice == "vehicle":
        near = near - 1  # do not count the ego itself
    best = int(np.argmax(near))  # first of the ties: candidates are in a stable order
    return candidates[best], int(near[best])


def scene_from_frame(log: TrafficLog, frame: FcdFrame, params: ExtractParams) -> Scene | None:
    """One scene for a frame, or None if no ego has ``min_vehicles`` vehicles within 48 m."""
    vehicles = frame_vehicles(log, frame)
    rsus = [rsu_agent(r) for r in log.rsus]
    ego, near = _pick_ego(vehicles, rsus, params.ego)
    if ego is None or near < params.min_vehicles:
        return None
    centre = (ego.x_m, ego.y_m)
    keep = [a for a in rsus + vehicles if np.hypot(a.x_m - centre[0], a.y_m - centre[1]) <= params.radius_m]
    disk = Point(centre).buffer(params.radius_m + 30.0)
    buildings = tuple(b for b in log.buildings if disk.intersects(Polygon(b.footprint_xy)))
    name = log.meta.town
    scene = Scene(
        scene_id=f"{name}_s{log.meta.seed}_t{frame.time_s:07.1f}_{ego.agent_id}",
        town=name, source=log.meta.source, time_s=frame.time_s, ego_id=ego.agent_id, agents=tuple(keep),
        buildings=buildings, lane_map=log.lane_map.crop(centre, params.radius_m + 30.0), log=str(log.directory),
    )
    if params.collaborators:
        rng = np.random.default_rng([log.meta.seed, int(round(frame.time_s * 10))])  # same frame, same pick
        scene = scene.with_collaborators(random_collaborators(scene, ego.agent_id, params.collaborators, rng) or ())
    return scene


def extract_scenes(log_path: str | Path, params: ExtractParams) -> Iterator[Scene]:
    """Scenes from every ``params.every``-th frame of a log folder."""
    params.validate()
    log = open_log(log_path)
    for i, frame in enumerate(f for f in log.frames() if f.time_s >= params.from_s - 1e-6):
        if i % params.every:
            continue
        scene = scene_from_frame(log, frame, params)
        if scene is not None:
            yield scene


def agents_at(log_path: str | Path, times_s: list[float]) -> dict[float, list[Agent]]:
    """Every vehicle (as agents) of the log's frames at ``times_s`` (seconds; matched to 1 ms),
    reading the log once up to the last of them. A time the log does not record is absent."""
    log = open_log(log_path)
    wanted = {round(t, 3) for t in times_s}
    last = max(wanted)
    out: dict[float, list[Agent]] = {}
    for frame in log.frames():
        t = round(frame.time_s, 3)
        if t in wanted:
            out[t] = frame_vehicles(log, frame)
        if t >= last:
            break
    return out


def log_period_s(log_path: str | Path) -> tuple[float, float]:
    """(recording period, first recorded time) of a log folder, seconds."""
    meta = open_log(log_path).meta
    return float(meta.record_period_s), float(meta.warmup_s)
