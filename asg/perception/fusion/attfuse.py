"""AttFuse: per-agent BEV features (each agent's points in the ego frame) fused per cell by
scaled dot-product attention across agents; the ego row is kept. Exposes that attention."""
from __future__ import annotations

import numpy as np
import torch

from ...sensors.frame import CooperativeFrame
from ..model import AttFuse
from .base import FUSIONS, AgentCloudsDetector


@FUSIONS.register("attfuse")
class AttFuseDetector(AgentCloudsDetector):
    weights = "attfuse"
    has_attention = True

    @classmethod
    def card_settings(cls, cfg) -> dict:
        return {"attfuse_fusion": cfg.attfuse_fusion}

    @classmethod
    def new_network(cls, cfg) -> torch.nn.Module:
        return AttFuse(cfg)

    @torch.no_grad()
    def attention_weights(self, frame: CooperativeFrame, cells: str = "all") -> dict[str, float]:
        """s_j: the ego row's attention toward agent j averaged over BEV cells (``all`` cells, or
        ``vehicles``: cells under ground-truth vehicles in range, as the paper's code does)."""
        att = self.model.ego_attention([self._sample(frame, self._clouds(frame))])[0].numpy()  # (N, H, W): row = y, column = x
        if cells == "vehicles":
            mask = self._vehicle_cells(frame, att.shape[1])
            if mask.any():
                return {a: float(att[j][mask].mean()) for j, a in enumerate(frame.sensing_ids)}
        return {a: float(att[j].mean()) for j, a in enumerate(frame.sensing_ids)}

    def _vehicle_cells(self, frame: CooperativeFrame, n: int) -> np.ndarray:
        mask = np.zeros((n, n), dtype=bool)
        step = 2 * self.cfg.range_m / n
        for b in frame.ego_boxes:
            ix = int((b[0] + self.cfg.range_m) // step)
            iy = int((b[1] + self.cfg.range_m) // step)
            if 0 <= ix < n and 0 <= iy < n:
                mask[iy, ix] = True
        return mask


@FUSIONS.register("attfuse-ft")
class AttFuseFinetunedDetector(AttFuseDetector):
    """AttFuse trained further on scenes attacked against it (``asg harden``); what it was trained
    on, how, and its AP before and after are in its card, asg/perception/weights/attfuse-ft.json."""

    weights = "attfuse-ft"
    fine_tuned_from = "attfuse"


@FUSIONS.register("attfuse-wide")
class AttFuseWideDetector(AttFuseDetector):
    """AttFuse on the wide PointPillars (configs/detectors/pointpillars-wide.yaml: the paper's
    filter widths): harder to attack than ``attfuse``; a frame costs about 1.6x AttFuse's (its
    network alone 2.3x); its sequence from the wide single-agent network is in its card."""

    weights = "attfuse-wide"
    config_file = "pointpillars-wide.yaml"
