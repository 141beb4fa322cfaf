"""No Fusion and Late Fusion share one single-agent PointPillars ('single' weights)."""
from __future__ import annotations

import numpy as np
import torch

from ...sensors.frame import CooperativeFrame, boxes_to_sensor, boxes_to_world
from ..feeds import OWN_CLOUD
from ..nms import select_boxes
from ..model import PointPillars, postprocess
from .base import FUSIONS, Detections, V2XDetector


class _Single(V2XDetector):
    weights = "single"
    feed = OWN_CLOUD

    @classmethod
    def new_network(cls, cfg) -> torch.nn.Module:
        return PointPillars(cfg)

    @torch.no_grad()
    def detect_own(self, clouds: list[np.ndarray]) -> list[Detections]:
        """Detections of each cloud in its own frame (each refined by the point stage from its own points)."""
        found = postprocess(self.model([torch.from_numpy(c) for c in clouds]), self.model, self.cfg)
        return [self.refined(boxes, scores, cloud) for (boxes, scores), cloud in zip(found, clouds)]


@FUSIONS.register("none")
class NoFusion(_Single):
    """The ego's own LiDAR only."""

    def detect(self, frame: CooperativeFrame) -> Detections:
        boxes, scores = self.detect_own([frame.clouds[frame.ego_id]])[0]
        return self._clip(boxes, scores)

    def seen_cloud(self, frame: CooperativeFrame) -> np.ndarray:
        """The ego's own cloud (N, 4): all No Fusion sees."""
        return frame.clouds[frame.ego_id]


@FUSIONS.register("late")
class LateFusion(_Single):
    """Each agent detects in its own frame; boxes are moved to the ego frame; one rotated NMS (with
    box voting, so agents seeing the same vehicle average their boxes)."""

    def detect(self, frame: CooperativeFrame) -> Detections:
        per_agent = self.detect_own([frame.clouds[a] for a in frame.sensing_ids])
        ego_pose = frame.poses[frame.ego_id]
        boxes, scores = [], []
        for aid, (b, s) in zip(frame.sensing_ids, per_agent):
            if len(b):
                boxes.append(boxes_to_sensor(boxes_to_world(b, frame.poses[aid]), ego_pose))
                scores.append(s)
        if not boxes:
            return np.zeros((0, 7)), np.zeros(0)
        b, s = np.vstack(boxes), np.concatenate(scores)
        return self._clip(*select_boxes(b, s, self.cfg))
