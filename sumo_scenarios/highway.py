"""highway-env as a second traffic source, recorded in the same log-folder format as SUMO runs.

highway-env draws with y pointing down; we mirror it (x, y) → (x, -y) and heading h → -h so that
the log is in a right-handed frame (x east, y north) with right-hand traffic, like SUMO's. Its
lanes become a :class:`LaneMap` (``lanes.json.gz``); lane ids are ``FROM_TO_k`` with k = 0 the
kerb-side (rightmost) lane, as in SUMO.
"""
from __future__ import annotations

import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from shapely.geometry import LineString, box

from . import checks
from .atomic import atomic_dir, remove_stale_partials_of
from .buildings import generate_buildings, write_buildings
from .errors import InputError
from .fcd import FcdFrame, FcdVehicle, front_from_center, sumo_angle_from_yaw_rad, write_fcd
from .lanes import Junction, Lane, LaneMap
from .log import BUILDINGS_NAME, FCD_NAME, LANES_NAME, LogMeta, density_stats, write_lanes, write_meta
from .rsu import place_rsus
from .simulate import MAX_SECONDS, validate_times

ENVS = ("highway-v0", "merge-v0", "roundabout-v0", "intersection-v0")
#: highway-env's vehicles are all 5 m x 2 m; we record them as this type (height is ours)
HWENV_TYPE = {"id": "car", "vclass": "passenger", "length_m": 5.0, "width_m": 2.0, "height_m": 1.5, "share": 1.0}

#: per scenario and density, the highway-env config overrides that set the traffic
DENSITY_CONFIG = {
    "highway-v0": {"normal": {"vehicles_count": 30, "vehicles_density": 1.0}, "dense": {"vehicles_count": 50, "vehicles_density": 1.6}},
    "merge-v0": {"normal": {}, "dense": {}},
    "roundabout-v0": {"normal": {}, "dense": {}},
    "intersection-v0": {"normal": {"spawn_probability": 0.6}, "dense": {"spawn_probability": 0.95}},
}


@dataclass(frozen=True)
class HighwayRequest:
    out_dir: Path
    env_id: str = "highway-v0"
    seed: int = 1
    duration_s: float = 60.0
    density: str = "normal"
    record_period_s: float = 0.5
    warmup_s: float = 0.0
    simulation_hz: int = 10

    def validate(self) -> None:
        if self.env_id not in ENVS:
            raise InputError(f"unknown highway-env scenario '{self.env_id}'; choose one of {', '.join(ENVS)}")
        validate_times(self.duration_s, self.warmup_s)
        checks.number(self.record_period_s, "--record-period (s)", 0.0, MAX_SECONDS, lo_open=True)
        if self.record_period_s * self.simulation_hz < 1 - 1e-9:
            raise InputError(f"--record-period must be at least one step ({1 / self.simulation_hz:g} s)")


def _make_env(req: HighwayRequest):
    os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
    import gymnasium as gym
    import highway_env  # noqa: F401  (registers the environments)

    config = {"duration": 10_000, "simulation_frequency": req.simulation_hz,
              "policy_frequency": max(1, round(1.0 / req.record_period_s)),
              **DENSITY_CONFIG[req.env_id][req.density]}
    env = gym.make(req.env_id, config=config)
    env.reset(seed=req.seed)
    return env.unwrapped


def _lane_id(frm: str, to: str, index: int, count: int) -> str:
    return f"{frm}_{to}_{count - 1 - index}"


def _lane_map(env, crop_box) -> LaneMap:
    """Sample highway-env lanes every 2 m inside ``crop_box`` (network frame), mirrored to y-up."""
    lanes = []
    graph = env.road.network.graph
    for frm in sorted(graph):
        for to in sorted(graph[frm]):
            group = graph[frm][to]
            for idx, lane in enumerate(group):
                s = np.append(np.arange(0.0, lane.length, 2.0), lane.length)
                pts = np.array([lane.position(float(v), 0.0) for v in s]) * np.array([1.0, -1.0])
                line = LineString(pts).intersection(crop_box)
                parts = [line] if line.geom_type == "LineString" else list(getattr(line, "geoms", []))
                parts = [p for p in parts if p.geom_type == "LineString" and p.length > 1.0]
                for k, part in enumerate(parts):
                    xy = np.asarray(part.simplify(0.05).coords)
                    lane_id = _lane_id(frm, to, idx, len(group)) + (f"#{k}" if k else "")
                    lanes.append(Lane(lane_id, xy, float(lane.width_at(0.0)), float(getattr(lane, "speed_limit", None) or 20.0)))
    junctions = []
    if env.spec is not None and env.spec.id in ("roundabout-v0", "intersection-v0"):
        junctions.append(Junction("center", np.zeros((0, 2)), "priority", (0.0, 0.0)))
    return LaneMap(lanes, junctions)


def _record_frame(env, time_s: float) -> FcdFrame:
    graph = env.road.network.graph
    out = []
    for k, v in enumerate(env.road.vehicles):
        x, y = float(v.position[0]), -float(v.position[1])
        yaw = -float(v.heading)
        fx, fy = front_from_center(x, y, yaw, HWENV_TYPE["length_m"])
        frm, to, idx = v.lane_index
        lane = _lane_id(frm, to, idx, len(graph[frm][to]))
        out.append(FcdVehicle(f"hw{id(v) % 10**9}" if k else "ego", fx, fy, 0.0, sumo_angle_from_yaw_rad(yaw), "car", float(v.speed), lane))
    return FcdFrame(time_s, tuple(out))


def simulate_highway(req: HighwayRequest, progress=None) -> dict:
    """Run a highway-env scenario and write a log folder (fcd, lanes, buildings, RSUs, meta)."""
    req.validate()
    env = _make_env(req)
    names: dict[int, str] = {}
    frames: list[FcdFrame] = []
    total = req.warmup_s + req.duration_s
    n_records = int(round(total / req.record_period_s))
    started = time.perf_counter()
    idle = 1  # DiscreteMetaAction IDLE: the ego keeps its lane and speed
    for i in range(n_records + 1):
        t = i * req.record_period_s
        if t >= req.warmup_s - 1e-9:
            frames.append(_stable_names(_record_frame(env, t), env, names))
        if i == n_records:
            break
        env.step(idle)
        if progress is not None:
            progress(t + req.record_period_s, total)
    wall = time.perf_counter() - started
    xy = np.array([[v.x_m, v.y_m] for f in frames for v in f.vehicles] or [[0.0, 0.0]])
    crop = box(*(xy.min(axis=0) - 150.0), *(xy.max(axis=0) + 150.0))
    lane_map = _lane_map(env, crop)
    buildings = generate_buildings(lane_map, req.seed)
    rsus = place_rsus(lane_map, buildings)
    stats = density_stats(frames, rsus, {"car": HWENV_TYPE["length_m"]})
    stats["wall_s"] = round(wall, 3)
    remove_stale_partials_of(req.out_dir)
    with atomic_dir(req.out_dir) as work:
        write_fcd(work / FCD_NAME, frames)
        write_lanes(work / LANES_NAME, lane_map)
        write_buildings(work / BUILDINGS_NAME, buildings)
        write_meta(work, LogMeta(
            source="highway-env", town=req.env_id.replace("-v0", ""), seed=req.seed, density=req.density,
            duration_s=req.duration_s, warmup_s=req.warmup_s, step_s=1.0 / req.simulation_hz,
            record_period_s=req.record_period_s, map_file=LANES_NAME, buildings_file=BUILDINGS_NAME,
            vehicle_types=(HWENV_TYPE,), rsus=tuple(r.to_dict() for r in rsus), stats=stats, env=req.env_id,
        ))
    return stats


def _stable_names(frame: FcdFrame, env, names: dict[int, str]) -> FcdFrame:
    """Give vehicles ids in order of first appearance (``veh0``, ``veh1``...), the ego ``ego``."""
    out = []
    for v, obj in zip(frame.vehicles, env.road.vehicles):
        if obj is env.vehicle:
            name = "ego"
        else:
            name = names.setdefault(id(obj), f"veh{len(names)}")
        out.append(FcdVehicle(name, v.x_m, v.y_m, v.z_m, v.angle_deg, v.type_id, v.speed_mps, v.lane_id))
    return FcdFrame(frame.time_s, tuple(out))
