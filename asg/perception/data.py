"""Detection samples: a scene's cooperative frame, with boxes and clouds in the frames each model
needs, and the augmentation used in training.

All boxes (M, 7) x, y, z, l, w, h, yaw; clouds (N, 4) float32; frames as named.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sumo_scenarios.geometry import wrap_rad

from ..scene import Scene
from ..scene.feasibility import EVAL_RANGE_M
from ..scene.views import Views
from ..sensors import LidarSpec, simulate_frame
from ..sensors.frame import CooperativeFrame, boxes_to_sensor, count_points_in_boxes


def in_range(boxes: np.ndarray, range_m: float = EVAL_RANGE_M) -> np.ndarray:
    return (np.abs(boxes[:, 0]) <= range_m) & (np.abs(boxes[:, 1]) <= range_m) if len(boxes) else np.zeros(0, bool)


def points_in_range_boxes(frame: CooperativeFrame) -> np.ndarray:
    """(M,) fused LiDAR points inside each ground-truth box within the evaluation range."""
    boxes = frame.ego_boxes
    return frame.points_in_boxes()["fused"][in_range(boxes)] if len(boxes) else np.zeros(0, dtype=int)


@dataclass
class Sample:
    """One frame for the detectors. ``clouds`` are in each agent's own sensor frame, ego first."""

    scene_id: str
    frame: CooperativeFrame

    @property
    def agents(self) -> tuple[str, ...]:
        return self.frame.sensing_ids

    def clouds_in_ego(self) -> list[np.ndarray]:
        return self.frame.clouds_in_frame_of(self.frame.ego_id)

    def gt_eval(self) -> np.ndarray:
        """Every vehicle (but the ego) within the evaluation range, ego frame: what AP counts."""
        b = self.frame.ego_boxes
        return b[in_range(b)]

    def gt_visible_ego(self, min_points: int = 1) -> np.ndarray:
        """Vehicles in range with at least ``min_points`` fused points: the fusion models' labels."""
        b = self.frame.ego_boxes
        fused = self.frame.points_in_boxes()["fused"]
        return b[in_range(b) & (fused >= min_points)]

    def own_views(self, min_points: int = 1) -> list[tuple[np.ndarray, np.ndarray]]:
        """(cloud, boxes) per agent in its own frame, boxes in range with ``min_points`` of its points."""
        f = self.frame
        out = []
        for a in f.sensing_ids:
            b = f.boxes_in(a)
            if f.sensing_ids and a != f.ego_id:
                b = np.vstack([b, _ego_box_in(f, a)])  # a collaborator sees the ego vehicle too
            n = count_points_in_boxes(f.clouds[a], b)
            out.append((f.clouds[a], b[in_range(b) & (n >= min_points)]))
        return out

    def detecting_agents(self, detecting: Views = Views.EGO) -> list[str]:
        """The detecting agent of each view :meth:`fused_views` gives, in its order."""
        return [self.frame.ego_id] if _views(detecting) is Views.EGO else list(self.frame.sensing_ids)

    def fused_views(self, detecting: Views = Views.EGO, min_points: int = 1) -> list[tuple[list[np.ndarray], np.ndarray]]:
        """Training views for the fusion models: per detecting agent, (every sensing agent's cloud
        in its frame, its own first; the boxes in its frame in range with ``min_points`` fused
        points). ``detecting``: ``Views.EGO`` (the ego only, as at inference) or ``Views.ALL`` (each
        sensing agent in turn: the same frame seen from 3 centres, 3 times the distinct examples).
        A detecting agent's own body is never a label (the ego's is not at inference either)."""
        f = self.frame
        detecting = _views(detecting)
        agents = self.detecting_agents(detecting)
        if detecting is Views.EGO:
            return [(self.clouds_in_ego(), self.gt_visible_ego(min_points))]
        out = []
        for a in agents:
            clouds = f.clouds_in_frame_of(a)
            boxes = f.boxes_in(a)
            if a != f.ego_id:  # its own body out, the ego vehicle in
                boxes = np.vstack([boxes[np.asarray(f.gt_ids) != a], _ego_box_in(f, a)])
            n = count_points_in_boxes(np.vstack(clouds), boxes)
            out.append((clouds, boxes[in_range(boxes) & (n >= min_points)]))
        return out


def _views(views: Views | str) -> Views:
    """``views`` as the closed set (its value accepted); ValueError naming the choices otherwise."""
    try:
        return Views(views)
    except ValueError:
        raise ValueError(f"views must be one of {[v.value for v in Views]}, not {views!r}") from None


def _ego_box_in(frame: CooperativeFrame, agent_id: str) -> np.ndarray:
    box = frame.ego_box_world
    if box is None:
        return np.zeros((0, 7))
    return boxes_to_sensor(box[None], frame.poses[agent_id])


def make_sample(scene: Scene, spec: LidarSpec) -> Sample:
    return Sample(scene.scene_id, simulate_frame(scene, spec))


@dataclass(frozen=True)
class Augmentation:
    """The random transform of each training example, the same for all its clouds and boxes: a
    flip across x (half of the examples, when ``flip``), a rotation about z drawn uniformly in
    [-rotate_deg, rotate_deg] and a scale drawn uniformly in [1 - scale, 1 + scale]. The draws
    are made whatever the settings, so a seeded run draws the same batches with any of them."""

    flip: bool = True
    rotate_deg: float = 45.0
    scale: float = 0.05


def augment(clouds: list[np.ndarray], boxes: np.ndarray, rng: np.random.Generator,
            aug: Augmentation = Augmentation()) -> tuple[list[np.ndarray], np.ndarray]:
    """``clouds`` (each (N, 4)) and ``boxes`` (M, 7) in one frame, transformed by ``aug``'s draw."""
    flip = bool(rng.random() < 0.5) and aug.flip
    angle = rng.uniform(-math.radians(aug.rotate_deg), math.radians(aug.rotate_deg))
    scale = rng.uniform(1.0 - aug.scale, 1.0 + aug.scale)
    c, s = math.cos(angle), math.sin(angle)
    rot = np.array([[c, -s], [s, c]])

    def tf_xy(xy: np.ndarray) -> np.ndarray:
        if flip:
            xy = xy * np.array([1.0, -1.0])
        return (xy @ rot.T) * scale

    out_clouds = []
    for p in clouds:
        q = p.copy()
        q[:, :2] = tf_xy(p[:, :2].astype(np.float64))
        q[:, 2] = p[:, 2] * scale
        out_clouds.append(q.astype(np.float32))
    b = boxes.copy()
    if len(b):
        b[:, :2] = tf_xy(boxes[:, :2])
        b[:, 2] *= scale
        b[:, 3:6] *= scale
        yaw = -boxes[:, 6] if flip else boxes[:, 6]
        b[:, 6] = wrap_rad(yaw + angle)
    return out_clouds, b
