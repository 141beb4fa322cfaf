"""F-Cooper: each agent's points in the ego frame through the shared pillar net and first stage,
fused by maxout per BEV cell and channel (asg.perception.model.MaxFuse). No attention: ACS-A
borrows the shipped AttFuse's."""
from __future__ import annotations

import torch

from ...registry import register
from ...sensors.frame import CooperativeFrame
from ..feeds import AGENT_CLOUDS
from ..model import MaxFuse, postprocess
from .base import Detections, V2XDetector


@register("fusion", "fcooper")
class FCooperDetector(V2XDetector):
    weights = "fcooper"
    feed = AGENT_CLOUDS

    @classmethod
    def new_network(cls, cfg) -> torch.nn.Module:
        return MaxFuse(cfg)

    @torch.no_grad()
    def detect(self, frame: CooperativeFrame) -> Detections:
        clouds = [torch.from_numpy(c) for c in frame.clouds_in_frame_of(frame.ego_id)]
        boxes, scores = postprocess(self.model([clouds]), self.model, self.cfg)[0]
        return self._clip(boxes, scores)
