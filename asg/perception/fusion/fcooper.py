"""F-Cooper: each agent's points in the ego frame through the shared pillar net and first stage,
fused by maxout per BEV cell and channel (asg.perception.model.MaxFuse). No attention: ACS-A
borrows the shipped AttFuse's."""
from __future__ import annotations

import torch

from ..model import MaxFuse
from .base import FUSIONS, AgentCloudsDetector


@FUSIONS.register("fcooper")
class FCooperDetector(AgentCloudsDetector):
    weights = "fcooper"

    @classmethod
    def new_network(cls, cfg) -> torch.nn.Module:
        return MaxFuse(cfg)
