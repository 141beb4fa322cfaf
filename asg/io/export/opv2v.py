"""OPV2V layout, as OpenCOOD's loaders read it: ``DIR/SCENE/AGENT/000000.pcd`` and ``000000.yaml``.

One scenario folder per scene, one timestamp (``000000``), one agent folder per sensing agent (the
ego and its collaborators). Agent ids are integers: vehicles ``1000 + i`` with the ego (if a vehicle)
first, roadside units negative (the OPV2V/V2XSet convention), numbered so that OpenCOOD's rule takes
our ego where it can (:func:`opencood_ego`). ``DIR/SCENE/ids.yaml`` maps our ids to these and names
our ego and the one OpenCOOD will take (OpenCOOD lists only folders).

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


def opv2v_ids(scene: Scene, sensing_ids: tuple[str, ...] | None = None) -> dict[str, int]:
    """Our agent id -> OPV2V integer id: vehicles 1000 + i, the ego vehicle first; RSUs negative,
    the sensing ones (``sensing_ids``, default the ego and its collaborators) first, numbered so
    that OpenCOOD's rule (:func:`opencood_ego`) takes our ego where the rule allows it: an RSU ego
    with other sensing RSUs is -2 (the rule moves the first negative folder, -1, to the end)."""
    sensing = set(sensing_ids if sensing_ids is not None else (scene.ego_id, *scene.collaborators))
    vehicles = sorted((a for a in scene.agents if a.kind == "vehicle"), key=lambda a: a.agent_id != scene.ego_id)
    ids = {a.agent_id: VEHICLE_ID_BASE + i for i, a in enumerate(vehicles)}
    rsus = sorted((a for a in scene.agents if a.kind == "rsu"), key=lambda a: (a.agent_id not in sensing, a.agent_id))
    numbers = list(range(1, len(rsus) + 1))
    sensing_rsus = [a for a in rsus if a.agent_id in sensing]
    if scene.ego.kind == "rsu" and 2 <= len(sensing_rsus) <= 9:  # one-digit ids: string order is numeric
        others = [a for a in sensing_rsus if a.agent_id != scene.ego_id]
        rsus = [others[0], scene.ego, *others[1:], *[a for a in rsus if a.agent_id not in sensing]]
    ids.update({a.agent_id: -n for a, n in zip(rsus, numbers)})
    return ids


def opencood_ego(folders: list[str]) -> str:
    """The agent folder OpenCOOD's OPV2V / V2XSet loaders take as the ego: the folder names sorted
    as strings, a leading negative (RSU) one moved to the end, then the first. With a vehicle ego
    and two or more sensing RSUs, or an RSU ego that is the only sensing RSU, no numbering makes it
    our ego (ids.yaml records both)."""
    order = sorted(folders)
    if order and int(order[0]) < 0:
        order = order[1:] + order[:1]
    return order[0]


def mirrored_pose(x_m: float, y_m: float, z_m: float, yaw_rad: float) -> list[float]:
    """[x, y, z, roll, yaw, pitch] in OPV2V's (CARLA's) left-handed frame, yaw in degrees."""
    return [float(x_m), float(-y_m), float(z_m), 0.0, float(-math.degrees(yaw_rad)), 0.0]


class ScenarioWriter:
    def __init__(self, out: Path, net: Path | None = None):
        self.out = out
        self.spec = load_lidar_spec()
        #: scenes whose ego OpenCOOD's rule cannot pick (ids.yaml: ``ego`` and ``opencood_ego``)
        self.other_ego: list[str] = []

    def write(self, scene: Scene) -> None:
        frame = simulate_frame(scene, self.spec)
        ids = opv2v_ids(scene, frame.sensing_ids)
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
        picked = int(opencood_ego([str(ids[a]) for a in frame.sensing_ids]))
        write_text_atomic(folder / "ids.yaml", yaml.safe_dump(
            {"scene_id": scene.scene_id, "ego": ids[scene.ego_id], "opencood_ego": picked,
             "sensing": [ids[a] for a in frame.sensing_ids],
             "ids": dict(ids), "frame": "CARLA left-handed: y and yaw mirrored from SUMO"},
            sort_keys=False))
        if picked != ids[scene.ego_id]:
            self.other_ego.append(scene.scene_id)

    def close(self) -> None:
        pass


def _vehicle_entry(agent) -> dict:
    x, y, z, _, yaw_deg, _ = mirrored_pose(agent.x_m, agent.y_m, agent.z_m, agent.yaw_rad)
    return {"location": [x, y, z], "center": [0.0, 0.0, float(agent.height_m / 2)],
            "extent": [float(agent.length_m / 2), float(agent.width_m / 2), float(agent.height_m / 2)],
            "angle": [0.0, yaw_deg, 0.0], "speed": float(agent.speed_mps * KMH_PER_MPS)}
