"""OPV2V layout, as OpenCOOD's loaders read it: ``DIR/SCENE/AGENT/000000.pcd`` and ``000000.yaml``.

One scenario folder per scene, one timestamp (``000000``), one agent folder per sensing agent (the
ego and its collaborators). Agent ids are integers, numbered so that OpenCOOD's ego rule takes our
ego (:func:`opv2v_ids`): the ego 0, other vehicles ``1000 + i``, a collaborating RSU -1 (further
ones ``9001, ...``). ``DIR/SCENE/ids.yaml`` maps our ids to these and names our ego and the one
OpenCOOD will take (the same).

The ego's view is written in a frame at a car's sensor height (asg.io.export.frames): an RSU or a
truck ego's cloud is raised and its ``lidar_pose`` lowered by ``ego_frame_lowered_m`` (ids.yaml),
so that OpenCOOD's fixed ground-truth range (z in [-3, 1] m around the ego's LiDAR) keeps every
vehicle.

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

import numpy as np
import yaml

from sumo_scenarios.atomic import write_text_atomic
from sumo_scenarios.checks import inside

from ...scene import Scene
from ...sensors import load_lidar_spec, simulate_frame
from ...sensors.frame import CooperativeFrame
from ..pcd import pcd_intensity_levels, write_pcd_rgb_intensity
from .frames import ego_frame_drop_m

TIMESTAMP = "000000"
#: the ego's id (any kind): "0" sorts before every other folder name but a negative one
EGO_ID = 0
#: first id of the other vehicles (four digits, so that string order is numeric order)
VEHICLE_ID_BASE = 1000
#: ids of the second and later sensing RSUs besides the ego (positive: see opv2v_ids)
EXTRA_RSU_ID_BASE = 9000
KMH_PER_MPS = 3.6


def opv2v_ids(scene: Scene, sensing_ids: tuple[str, ...] | None = None) -> dict[str, int]:
    """Our agent id -> OPV2V integer id, numbered so that OpenCOOD's rule (:func:`opencood_ego`)
    takes our ego, whatever its kind: the ego EGO_ID (0, the smallest folder name but a negative
    one); the other vehicles ``1000 + i``; the first other sensing RSU -1 (the OPV2V / V2XSet
    convention: the rule moves one negative folder to the end), further sensing RSUs ``9001, ...``
    (a second negative folder would be the rule's ego); RSUs that do not sense -2, -3, ... (no
    folder). ``sensing_ids``: default the ego and its collaborators."""
    sensing = sensing_ids if sensing_ids is not None else (scene.ego_id, *scene.collaborators)
    ids = {scene.ego_id: EGO_ID}
    vehicles = [a.agent_id for a in scene.agents if a.kind == "vehicle" and a.agent_id != scene.ego_id]
    ids.update({a: VEHICLE_ID_BASE + i for i, a in enumerate(vehicles)})
    sensing_rsus = [a for a in sensing if a != scene.ego_id and scene.agent(a).kind == "rsu"]
    ids.update({a: (-1 if i == 0 else EXTRA_RSU_ID_BASE + i) for i, a in enumerate(sensing_rsus)})
    quiet = [a.agent_id for a in scene.agents if a.kind == "rsu" and a.agent_id not in ids]
    ids.update({a: -2 - i for i, a in enumerate(quiet)})
    return ids


def opencood_ego(folders: list[str]) -> str:
    """The agent folder OpenCOOD's OPV2V / V2XSet loaders take as the ego: the folder names sorted
    as strings, a leading negative (RSU) one moved to the end, then the first. :func:`opv2v_ids`
    numbers the folders so that this is always our ego."""
    order = sorted(folders)
    if order and int(order[0]) < 0:
        order = order[1:] + order[:1]
    return order[0]


def mirrored_pose(x_m: float, y_m: float, z_m: float, yaw_rad: float) -> list[float]:
    """[x, y, z, roll, yaw, pitch] in OPV2V's (CARLA's) left-handed frame, yaw in degrees."""
    return [float(x_m), float(-y_m), float(z_m), 0.0, float(-math.degrees(yaw_rad)), 0.0]


def agent_views(frame: CooperativeFrame, ids: dict[str, int], scene: Scene | None = None) -> tuple[dict, float]:
    """Each sensing agent's view as OpenCOOD reads it from this layout, in memory: ({agent id:
    (meta, cloud)}, how far the ego's frame is lowered in m). ``meta``: the agent's yaml
    (lidar_pose, true_ego_pos, ego_speed, vehicles: {OPV2V id: box entry}, every vehicle but itself);
    ``cloud``: (N, 4) float32 x, y, z, intensity in its sensor frame, mirrored (and the ego's raised),
    intensity quantised to the PCD's 8-bit colour. ``scene``: the scene's agents (the boxes, the
    speeds); without it (a detector's input) no vehicles are listed and the bodies are the sensors."""
    ego_pose = frame.poses[frame.ego_id]
    lowered_m = ego_frame_drop_m(ego_pose.z_m, frame.ground_z_m.get(frame.ego_id, ego_pose.z_m))
    vehicles = {} if scene is None else {a.agent_id: _vehicle_entry(a) for a in scene.agents if a.kind == "vehicle"}
    views = {}
    for agent_id in frame.sensing_ids:
        pose = frame.poses[agent_id]
        drop_m = lowered_m if agent_id == frame.ego_id else 0.0  # the ego's frame at a car's sensor height
        cloud = frame.clouds[agent_id].astype(np.float32)
        cloud[:, 1] = -cloud[:, 1]
        cloud[:, 2] += drop_m
        cloud[:, 3] = (pcd_intensity_levels(cloud[:, 3]) / 255.0).astype(np.float32)
        lidar_pose = mirrored_pose(pose.x_m, pose.y_m, pose.z_m - drop_m, pose.yaw_rad)
        if scene is None:
            body, speed_mps = mirrored_pose(pose.x_m, pose.y_m, frame.ground_z_m.get(agent_id, pose.z_m), pose.yaw_rad), 0.0
        else:
            agent = scene.agent(agent_id)
            body, speed_mps = mirrored_pose(agent.x_m, agent.y_m, agent.z_m, agent.yaw_rad), agent.speed_mps
        meta = {"lidar_pose": lidar_pose, "true_ego_pos": body, "predicted_ego_pos": body,
                "ego_speed": float(speed_mps * KMH_PER_MPS),
                "vehicles": {ids[v]: entry for v, entry in vehicles.items() if v != agent_id}}
        views[agent_id] = (meta, cloud)
    return views, lowered_m


class ScenarioWriter:
    def __init__(self, out: Path, net: Path | None = None):
        self.out = out
        self.spec = load_lidar_spec()

    def write(self, scene: Scene) -> None:
        frame = simulate_frame(scene, self.spec)
        ids = opv2v_ids(scene, frame.sensing_ids)
        folder = inside(self.out, self.out / scene.scene_id)
        views, lowered_m = agent_views(frame, ids, scene)
        for agent_id, (meta, cloud) in views.items():
            agent_dir = folder / str(ids[agent_id])
            agent_dir.mkdir(parents=True, exist_ok=True)
            write_pcd_rgb_intensity(agent_dir / f"{TIMESTAMP}.pcd", cloud)
            write_text_atomic(agent_dir / f"{TIMESTAMP}.yaml", yaml.safe_dump(meta, sort_keys=False))
        picked = int(opencood_ego([str(ids[a]) for a in frame.sensing_ids]))
        write_text_atomic(folder / "ids.yaml", yaml.safe_dump(
            {"scene_id": scene.scene_id, "ego": ids[scene.ego_id], "opencood_ego": picked,
             "sensing": [ids[a] for a in frame.sensing_ids],
             "ids": dict(ids), "frame": "CARLA left-handed: y and yaw mirrored from SUMO",
             "ego_frame_lowered_m": lowered_m},
            sort_keys=False))

    def close(self) -> None:
        pass


def _vehicle_entry(agent) -> dict:
    x, y, z, _, yaw_deg, _ = mirrored_pose(agent.x_m, agent.y_m, agent.z_m, agent.yaw_rad)
    return {"location": [x, y, z], "center": [0.0, 0.0, float(agent.height_m / 2)],
            "extent": [float(agent.length_m / 2), float(agent.width_m / 2), float(agent.height_m / 2)],
            "angle": [0.0, yaw_deg, 0.0], "speed": float(agent.speed_mps * KMH_PER_MPS)}
