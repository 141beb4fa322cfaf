"""The cooperative frame: what every sensing agent's LiDAR sees in one scene, with labels.

Frames and units: each cloud is (N, 4) float32 x, y, z, intensity in its own sensor frame
(origin at the LiDAR, x forward, y left, z up, metres). Boxes are (M, 7) float64 x, y, z, l, w, h,
yaw with (x, y, z) the box centre; ``boxes_in(agent)`` gives them in that agent's sensor frame,
``gt_boxes_world`` in the network frame.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Callable, Mapping, Sequence

import numpy as np

from sumo_scenarios.errors import InputError
from sumo_scenarios.geometry import wrap_rad

from ..scene import Agent, Scene
from ..scene.link import LinkState
from .lidar_spec import LidarSpec
from .world import SensorPose, World


@dataclass(frozen=True)
class CooperativeFrame:
    scene_id: str
    ego_id: str
    sensing_ids: tuple[str, ...]
    poses: dict[str, SensorPose]
    clouds: dict[str, np.ndarray]
    gt_ids: tuple[str, ...]
    gt_boxes_world: np.ndarray
    #: the ego's own box if the ego is a vehicle (collaborators should detect it), else None
    ego_box_world: np.ndarray | None = None
    #: each sensing agent's kind, "vehicle" or "rsu" (an agent not listed counts as a vehicle)
    agent_kinds: Mapping[str, str] = field(default_factory=dict)
    #: how old each delayed agent's cloud is at the frame's instant (s; the link's message delay,
    #: known to the receiver from the message's time stamp); an agent not listed: 0, current
    agent_delays_s: Mapping[str, float] = field(default_factory=dict)
    #: the ground height (m, network frame) under each sensing agent; an agent not listed: unknown
    ground_z_m: Mapping[str, float] = field(default_factory=dict)

    def boxes_in(self, agent_id: str) -> np.ndarray:
        """Ground-truth boxes (M, 7) in ``agent_id``'s sensor frame."""
        return boxes_to_sensor(self.gt_boxes_world, self.poses[agent_id])

    @property
    def ego_boxes(self) -> np.ndarray:
        return self.boxes_in(self.ego_id)

    def cloud_in(self, agent_id: str, frame_of: str) -> np.ndarray:
        """``agent_id``'s cloud moved into ``frame_of``'s sensor frame (N, 4)."""
        return transform_points(self.clouds[agent_id], self.poses[agent_id], self.poses[frame_of])

    def clouds_in_frame_of(self, frame_of: str) -> list[np.ndarray]:
        """Every sensing agent's cloud (N_i, 4) moved into ``frame_of``'s sensor frame, its own
        first (untouched), then the others in sensing order (for the ego: sensing order)."""
        own, *others = self.agents_from(frame_of)
        return [self.clouds[own]] + [self.cloud_in(a, frame_of) for a in others]

    def agents_from(self, frame_of: str) -> list[str]:
        """``frame_of`` first, then the other sensing agents in sensing order: the order of
        :meth:`clouds_in_frame_of` and :meth:`kinds_in_frame_of`."""
        return [frame_of] + [a for a in self.sensing_ids if a != frame_of]

    def kinds_in_frame_of(self, frame_of: str) -> tuple[str, ...]:
        """The kind ("vehicle" or "rsu") of each cloud :meth:`clouds_in_frame_of` gives, in its order."""
        return tuple(self.agent_kinds.get(a, "vehicle") for a in self.agents_from(frame_of))

    def delays_in_frame_of(self, frame_of: str) -> tuple[float, ...]:
        """The age (s) of each cloud :meth:`clouds_in_frame_of` gives, in its order."""
        return tuple(float(self.agent_delays_s.get(a, 0.0)) for a in self.agents_from(frame_of))

    def points_in_boxes(self) -> dict[str, np.ndarray]:
        """Points inside each ground-truth box, per sensing agent and ``"fused"`` (their sum): (M,) int."""
        out = {aid: count_points_in_boxes(self.clouds[aid], self.boxes_in(aid)) for aid in self.sensing_ids}
        out["fused"] = np.sum([out[a] for a in self.sensing_ids], axis=0) if self.sensing_ids else np.zeros(len(self.gt_ids), int)
        return out


def boxes_to_sensor(boxes_world: np.ndarray, pose: SensorPose) -> np.ndarray:
    """(M, 7) network-frame boxes → the sensor frame of ``pose``."""
    if not len(boxes_world):
        return np.zeros((0, 7))
    c, s = math.cos(pose.yaw_rad), math.sin(pose.yaw_rad)
    d = boxes_world[:, :3] - pose.origin
    out = boxes_world.copy()
    out[:, 0] = c * d[:, 0] + s * d[:, 1]
    out[:, 1] = -s * d[:, 0] + c * d[:, 1]
    out[:, 2] = d[:, 2]
    out[:, 6] = wrap_rad(boxes_world[:, 6] - pose.yaw_rad)
    return out


def boxes_to_world(boxes: np.ndarray, pose: SensorPose) -> np.ndarray:
    """(M, 7) boxes in the sensor frame of ``pose`` → network frame (inverse of boxes_to_sensor)."""
    c, s = math.cos(pose.yaw_rad), math.sin(pose.yaw_rad)
    out = boxes.copy()
    out[:, 0] = c * boxes[:, 0] - s * boxes[:, 1] + pose.x_m
    out[:, 1] = s * boxes[:, 0] + c * boxes[:, 1] + pose.y_m
    out[:, 2] = boxes[:, 2] + pose.z_m
    out[:, 6] = boxes[:, 6] + pose.yaw_rad
    return out


def transform_points(points: np.ndarray, src: SensorPose, dst: SensorPose) -> np.ndarray:
    """(N, 4) points from sensor frame ``src`` to sensor frame ``dst`` (intensity kept)."""
    world = points[:, :3].astype(np.float64) @ src.rotation().T + src.origin
    local = (world - dst.origin) @ dst.rotation()
    out = points.copy()
    out[:, :3] = local
    return out


def count_points_in_boxes(points: np.ndarray, boxes: np.ndarray, margin_m: float = 0.02) -> np.ndarray:
    """Number of points (N, >=3) inside each box (M, 7), all in one frame; boxes grown by ``margin_m``."""
    if not len(boxes) or not len(points):
        return np.zeros(len(boxes), dtype=np.int64)
    p = points[:, :3].astype(np.float64)
    counts = np.zeros(len(boxes), dtype=np.int64)
    for i, (x, y, z, l, w, h, yaw) in enumerate(boxes):
        r = math.hypot(l, w) / 2 + margin_m
        near = (np.abs(p[:, 0] - x) <= r) & (np.abs(p[:, 1] - y) <= r)
        if not near.any():
            continue
        q = p[near] - (x, y, z)
        c, s = math.cos(yaw), math.sin(yaw)
        lx = c * q[:, 0] + s * q[:, 1]
        ly = -s * q[:, 0] + c * q[:, 1]
        inside = (np.abs(lx) <= l / 2 + margin_m) & (np.abs(ly) <= w / 2 + margin_m) & (np.abs(q[:, 2]) <= h / 2 + margin_m)
        counts[i] = int(inside.sum())
    return counts


def ground_truth(scene: Scene, moved: Mapping[str, Agent | None] | None = None) -> tuple[tuple[str, ...], np.ndarray]:
    """Ids and network-frame boxes (M, 7) of every vehicle but the ego (``moved``: new poses by
    id, None = absent)."""
    moved = moved or {}
    vehicles = [moved.get(a.agent_id, a) for a in scene.vehicles if a.agent_id != scene.ego_id]
    vehicles = [a for a in vehicles if a is not None]
    if not vehicles:
        return (), np.zeros((0, 7))
    return tuple(a.agent_id for a in vehicles), np.stack([a.box7() for a in vehicles])


def render_frame(world: World, sensing_ids: Sequence[str] | None = None, moved: Mapping[str, Agent | None] | None = None,
                 seed: int = 0) -> CooperativeFrame:
    """Render the cooperative frame of ``world.scene`` for its sensing agents (ego + collaborators),
    as the ego receives it: the scene's link record applied (see :func:`apply_link`)."""
    scene = world.scene
    ids = tuple(sensing_ids) if sensing_ids is not None else scene.sensing_ids
    if not ids:
        raise InputError(f"scene {scene.scene_id}: no sensing agent")
    clouds = world.render_many(ids, moved, seed)
    gt_ids, gt = ground_truth(scene, moved)
    ego_box = scene.ego.box7() if scene.ego.is_vehicle else None
    kinds = {a.agent_id: a.kind for a in scene.agents if a.agent_id in ids}
    frame = CooperativeFrame(scene.scene_id, scene.ego_id, ids, {a: world.sensor_pose(a) for a in ids}, clouds, gt_ids,
                             gt, ego_box, kinds, ground_z_m={a.agent_id: a.z_m for a in scene.agents if a.agent_id in ids})
    if not scene.link:
        return frame
    return apply_link(frame, scene.link, lambda aid, state: delayed_view(scene, aid, state, world.spec, seed))


#: a delayed message: the collaborator's cloud (N, 4) in its sensor frame of that earlier instant, and that pose
DelayedView = Callable[[str, LinkState], tuple[np.ndarray, SensorPose]]


def delayed_view(scene: Scene, agent_id: str, state: LinkState, spec: LidarSpec, seed: int = 0) -> tuple[np.ndarray, SensorPose]:
    """What collaborator ``agent_id`` sensed ``state.delay_s`` earlier: its cloud rendered in the
    world of that instant (``state.earlier_agents`` with the scene's buildings) and its sensor pose then."""
    earlier = replace(scene, agents=state.earlier_agents, link={}, collaborators=(agent_id,),
                      ego_id=agent_id)
    world = World(earlier, spec)
    return world.render(agent_id, seed=seed), world.sensor_pose(agent_id)


def apply_link(frame: CooperativeFrame, link: Mapping[str, LinkState], delayed: DelayedView) -> CooperativeFrame:
    """The frame as the ego receives it over a V2X link (see asg.scene.link): a delayed
    collaborator's cloud and pose replaced by ``delayed(id, state)``, a pose error added to the
    shared pose, a dropped message removed, each delay recorded (``agent_delays_s``). Ground truth
    and the ego are untouched."""
    ids, poses, clouds, delays_s = [], dict(frame.poses), dict(frame.clouds), dict(frame.agent_delays_s)
    for aid in frame.sensing_ids:
        state = link.get(aid) if aid != frame.ego_id else None
        if state is None or state.is_perfect:
            ids.append(aid)
            continue
        if state.dropped:
            poses.pop(aid)
            clouds.pop(aid)
            continue
        if state.delay_s > 0:
            clouds[aid], poses[aid] = delayed(aid, state)
            delays_s[aid] = float(state.delay_s)
        p = poses[aid]
        poses[aid] = SensorPose(p.x_m + state.dx_m, p.y_m + state.dy_m, p.z_m,
                                wrap_rad(p.yaw_rad + state.dyaw_rad))
        ids.append(aid)
    return replace(frame, sensing_ids=tuple(ids), poses=poses, clouds=clouds,
                   agent_delays_s={a: d for a, d in delays_s.items() if a in ids})


def simulate_frame(scene: Scene, spec: LidarSpec, seed: int = 0) -> CooperativeFrame:
    """Build the world of ``scene`` (the renderer its source picks) and render its sensing agents once."""
    from .renderers import world_for

    if scene.is_empty:
        raise InputError(f"scene {scene.scene_id}: empty scene (no vehicles, no buildings); pick another frame")
    return render_frame(world_for(scene, spec), seed=seed)
