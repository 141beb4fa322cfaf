"""OPV2V layout, as OpenCOOD's loaders read it: ``DIR/SCENE/AGENT/000000.pcd`` and ``000000.yaml``.

One scenario folder per scene, one timestamp (``000000``), one agent folder per sensing agent (the
ego and its collaborators). Agent ids are integers: vehicles ``1000 + i`` with the ego (if a vehicle)
first, so that it sorts first and OpenCOOD takes it as the ego; roadside units ``-1, -2, ...`` (the
OPV2V/V2XSet convention). ``DIR/SCENE/ids.yaml`` maps our ids to these (OpenCOOD lists only folders).

Frames: OPV2V's worlds are CARLA's, left-handed (x forward, y right); ours are right-handed (SUMO's
x east, y north; sensors x forward, y left). The export mirrors y: world ``(x, y, z)`` is written as
``(x, -y, z)``, every yaw as ``-yaw`` (degrees), and every point's sensor-frame y as ``-y``, so that
OpenCOOD's ``x_to_world`` and ``project_world_objects`` put each box where our ground truth has it
(mirrored). ``lidar_pose`` and a vehicle's ``angle`` are [roll, yaw, pitch] in degrees (roll and
pitch 0: our towns are flat per scene); ``location`` is the box's ground point, ``center`` its
offset to the box centre ``[0, 0, h/2]``, ``extent`` half-sizes; speeds in km/h as OPV2V's.
"""
from __future__ import annotations

import math
from pathlib import Path

import yaml

from sumo_scenarios.atomic import write_text_atomic
from sumo_scenarios.checks import inside

from ...scene import Scene
from ...sensors import load_lidar_spec, simulate_frame
from ..pcd import write_pcd_rgb_intensity

TIMESTAMP = "000000"
#: first id of the vehicles (four digits, so that string order is numeric order)
VEHICLE_ID_BASE = 1000
KMH_PER_MPS = 3.6


def opv2v_ids(scene: Scene) -> dict[str, int]:
    """Our agent id -> OPV2V integer id: vehicles 1000 + i, the ego vehicle first; RSUs -1, -2, ...
    (an RSU ego -1)."""
    vehicles = sorted((a for a in scene.agents if a.kind == "vehicle"), key=lambda a: a.agent_id != scene.ego_id)
    rsus = sorted((a for a in scene.agents if a.kind == "rsu"), key=lambda a: a.agent_id != scene.ego_id)
    ids = {a.agent_id: VEHICLE_ID_BASE + i for i, a in enumerate(vehicles)}
    ids.update({a.agent_id: -(i + 1) for i, a in enumerate(rsus)})
    return ids


def mirrored_pose(x_m: float, y_m: float, z_m: float, yaw_rad: float) -> list[float]:
    """[x, y, z, roll, yaw, pitch] in OPV2V's (CARLA's) left-handed frame, yaw in degrees."""
    return [float(x_m), float(-y_m), float(z_m), 0.0, float(-math.degrees(yaw_rad)), 0.0]


class ScenarioWriter:
    def __init__(self, out: Path, net: Path | None = None):
        self.out = out
        self.spec = load_lidar_spec("v2xp")

    def write(self, scene: Scene) -> None:
        frame = simulate_frame(scene, self.spec)
        ids = opv2v_ids(scene)
        folder = inside(self.out, self.out / scene.scene_id)
        vehicles = {a.agent_id: _vehicle_entry(a) for a in scene.agents if a.kind == "vehicle"}
        for agent_id in frame.sensing_ids:
            pose = frame.poses[agent_id]
            agent_dir = folder / str(ids[agent_id])
            agent_dir.mkdir(parents=True, exist_ok=True)
            cloud = frame.clouds[agent_id].copy()
            cloud[:, 1] = -cloud[:, 1]
            write_pcd_rgb_intensity(agent_dir / f"{TIMESTAMP}.pcd", cloud)
            agent = scene.agent(agent_id)
            lidar_pose = mirrored_pose(pose.x_m, pose.y_m, pose.z_m, pose.yaw_rad)
            body = mirrored_pose(agent.x_m, agent.y_m, agent.z_m, agent.yaw_rad)
            meta = {"lidar_pose": lidar_pose, "true_ego_pos": body, "predicted_ego_pos": body,
                    "ego_speed": float(agent.speed_mps * KMH_PER_MPS),
                    "vehicles": {ids[v]: entry for v, entry in vehicles.items() if v != agent_id}}
            write_text_atomic(agent_dir / f"{TIMESTAMP}.yaml", yaml.safe_dump(meta, sort_keys=False))
        write_text_atomic(folder / "ids.yaml", yaml.safe_dump(
            {"scene_id": scene.scene_id, "ego": ids[scene.ego_id], "sensing": [ids[a] for a in frame.sensing_ids],
             "ids": dict(ids), "frame": "CARLA left-handed: y and yaw mirrored from SUMO"},
            sort_keys=False))

    def close(self) -> None:
        pass


def _vehicle_entry(agent) -> dict:
    x, y, z, _, yaw_deg, _ = mirrored_pose(agent.x_m, agent.y_m, agent.z_m, agent.yaw_rad)
    return {"location": [x, y, z], "center": [0.0, 0.0, float(agent.height_m / 2)],
            "extent": [float(agent.length_m / 2), float(agent.width_m / 2), float(agent.height_m / 2)],
            "angle": [0.0, yaw_deg, 0.0], "speed": float(agent.speed_mps * KMH_PER_MPS)}
