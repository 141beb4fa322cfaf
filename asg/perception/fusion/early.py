"""Early Fusion: every agent's points moved to the ego frame, one PointPillars pass."""
from __future__ import annotations

import numpy as np
import torch

from ...sensors.frame import CooperativeFrame
from ..feeds import FUSED_CLOUD
from ..model import PointPillars, postprocess
from .base import FUSIONS, Detections, V2XDetector


def fused_cloud(frame: CooperativeFrame) -> np.ndarray:
    return np.vstack(frame.clouds_in_frame_of(frame.ego_id))


@FUSIONS.register("early")
class EarlyFusion(V2XDetector):
    weights = "early"
    feed = FUSED_CLOUD

    @classmethod
    def new_network(cls, cfg) -> torch.nn.Module:
        return PointPillars(cfg)

    @torch.no_grad()
    def detect(self, frame: CooperativeFrame) -> Detections:
        cloud = fused_cloud(frame)
        boxes, scores = postprocess(self.model([torch.from_numpy(cloud)]), self.model, self.cfg)[0]
        return self._clip(*self.refined(boxes, scores, cloud))
