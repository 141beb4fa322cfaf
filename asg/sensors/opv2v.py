"""The OPV2V layout's conventions for a cooperative frame (what ``asg export --format opv2v`` writes
and OpenCOOD's loaders read), in memory: agent ids numbered so that OpenCOOD takes our ego, the
left-handed (CARLA) frame with y and yaw mirrored, the ego's view lowered to a car's sensor height
(asg.sensors.ego_frame), each agent's yaml and cloud. Used by the export (asg.io.export.opv2v) and by
the OpenCOOD adapter (asg.perception.opencood), which feeds OpenCOOD the same data without files.
"""
from __future__ import annotations

import math

import numpy as np

from ..scene import Agent, Scene
from ..scene.recording import opencood_ego  # noqa: F401  (the layout's ego rule, read by the import too)
from .ego_frame import ego_frame_drop_m
from .frame import CooperativeFrame

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
    vehicles = [a.agent_id for a in scene.agents if a.kind == "vehicle" and a.agent_id != scene.ego_id]
    sensing_rsus = [a for a in sensing if a != scene.ego_id and scene.agent(a).kind == "rsu"]
    ids = _numbered(scene.ego_id, vehicles, sensing_rsus)
    quiet = [a.agent_id for a in scene.agents if a.kind == "rsu" and a.agent_id not in ids]
    ids.update({a: -2 - i for i, a in enumerate(quiet)})
    return ids


def frame_ids(frame: CooperativeFrame, every_vehicle: bool = False) -> dict[str, int]:
    """:func:`opv2v_ids` of a frame's sensing agents (``every_vehicle``: and of every vehicle of its
    ground truth), from the frame alone (its ground truth lists the scene's other vehicles in the
    scene's order)."""
    sensing_rsus = [a for a in frame.sensing_ids if a != frame.ego_id and frame.agent_kinds.get(a, "vehicle") == "rsu"]
    ids = _numbered(frame.ego_id, frame.gt_ids, sensing_rsus)
    return ids if every_vehicle else {a: ids[a] for a in frame.sensing_ids}


def _numbered(ego_id: str, vehicles, sensing_rsus) -> dict[str, int]:
    """The ego EGO_ID, ``vehicles`` (the other vehicles, in the scene's order) 1000 + i, the first of
    ``sensing_rsus`` -1, further ones 9001, ... (see :func:`opv2v_ids`)."""
    ids = {ego_id: EGO_ID}
    ids.update({a: VEHICLE_ID_BASE + i for i, a in enumerate(vehicles)})
    ids.update({a: (-1 if i == 0 else EXTRA_RSU_ID_BASE + i) for i, a in enumerate(sensing_rsus)})
    return ids


def mirrored_pose(x_m: float, y_m: float, z_m: float, yaw_rad: float) -> list[float]:
    """[x, y, z, roll, yaw, pitch] in OPV2V's (CARLA's) left-handed frame, yaw in degrees."""
    return [float(x_m), float(-y_m), float(z_m), 0.0, float(-math.degrees(yaw_rad)), 0.0]


def agent_views(frame: CooperativeFrame, ids: dict[str, int], scene: Scene | None = None,
                labelled: bool = False) -> tuple[dict, dict]:
    """Each sensing agent's view as OpenCOOD reads it from this layout, in memory: ({agent id:
    (meta, cloud)}, {agent id: how far its frame is lowered, m}). ``meta``: the agent's yaml
    (lidar_pose, true_ego_pos, ego_speed, vehicles: {OPV2V id: box entry}, every vehicle but itself);
    ``cloud``: (N, 4) float32 x, y, z, intensity in its sensor frame, mirrored, intensity quantised
    to the PCD's 8-bit colour. Every agent whose sensor stands high (an RSU's pole, a truck's roof)
    has its frame lowered to a car's sensor height (asg.sensors.ego_frame): its cloud raised, its
    lidar_pose lowered by the same, so that OpenCOOD's ground-truth range around each agent's LiDAR
    (late fusion's per-agent labels) keeps its vehicles, and every projection between agents stays
    exact. ``scene``: the scene's agents (the boxes, the speeds); without it (a detector's input) no
    vehicles are listed and the bodies are the sensors, unless ``labelled``: then the frame's own
    ground truth (every vehicle but the ego, and the ego's box) is listed, at speed 0."""
    drops = {a: ego_frame_drop_m(frame.poses[a].z_m, frame.ground_z_m.get(a, frame.poses[a].z_m))
             for a in frame.sensing_ids}
    if scene is not None:
        vehicles = {a.agent_id: _vehicle_entry(a) for a in scene.agents if a.kind == "vehicle"}
    else:
        vehicles = frame_labels(frame) if labelled else {}
    views = {}
    for agent_id in frame.sensing_ids:
        pose = frame.poses[agent_id]
        drop_m = drops[agent_id]
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
                "ego_speed": float(speed_mps * KMH_PER_MPS), "RSU": frame.agent_kinds.get(agent_id) == "rsu",
                "vehicles": {ids[v]: entry for v, entry in vehicles.items() if v != agent_id}}
        views[agent_id] = (meta, cloud)
    return views, drops


def frame_labels(frame: CooperativeFrame) -> dict[str, dict]:
    """{vehicle id: its yaml entry} of every vehicle a frame's ground truth holds, the ego's own box
    among them (what the scene's agents give an export, from the frame alone; speeds 0)."""
    boxes = list(zip(frame.gt_ids, frame.gt_boxes_world))
    if frame.ego_box_world is not None:
        boxes.append((frame.ego_id, frame.ego_box_world))
    out = {}
    for vid, (x, y, zc, length, width, height, yaw) in boxes:
        agent = Agent(vid, "vehicle", "car", x, y, zc - height / 2, yaw, length, width, height)
        out[vid] = _vehicle_entry(agent)
    return out


def _vehicle_entry(agent) -> dict:
    x, y, z, _, yaw_deg, _ = mirrored_pose(agent.x_m, agent.y_m, agent.z_m, agent.yaw_rad)
    return {"location": [x, y, z], "center": [0.0, 0.0, float(agent.height_m / 2)],
            "extent": [float(agent.length_m / 2), float(agent.width_m / 2), float(agent.height_m / 2)],
            "angle": [0.0, yaw_deg, 0.0], "speed": float(agent.speed_mps * KMH_PER_MPS),
            "obj_type": agent.type_id}  # V2V4Real's key; OpenCOOD's OPV2V reader ignores it


def pcd_intensity_levels(intensity: np.ndarray) -> np.ndarray:
    """(N,) uint32 8-bit colour levels of intensities (N,) in [0, 1] (clipped), as the rgb PCD stores them."""
    return np.round(np.clip(intensity, 0.0, 1.0) * 255.0).astype(np.uint32)
