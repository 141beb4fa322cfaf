"""A fake detector for fast search tests: ground truth for every box with enough fused points."""
from __future__ import annotations

import numpy as np
import torch

from asg.perception.fusion.base import V2XDetector
from asg.sensors.frame import CooperativeFrame


class OracleDetector(V2XDetector):
    """Detects exactly the vehicles (in range) with at least ``min_points`` LiDAR points, score by visibility."""

    def __init__(self, min_points: int = 30):
        self.min_points = min_points
        super().__init__(load=False)

    def build_model(self) -> torch.nn.Module:
        return torch.nn.Identity()

    def detect(self, frame: CooperativeFrame):
        boxes = frame.ego_boxes
        n = frame.points_in_boxes()["fused"]
        keep = n >= self.min_points
        scores = np.clip(n[keep] / 200.0, 0.21, 1.0)
        return self._clip(boxes[keep], scores)

    def attention_weights(self, frame: CooperativeFrame, cells: str = "all") -> dict[str, float]:
        """Weights proportional to each agent's point count (a stand-in for AttFuse's attention)."""
        counts = {a: float(len(frame.clouds[a])) for a in frame.sensing_ids}
        total = sum(counts.values())
        return {a: c / total for a, c in counts.items()}


def oracle_factory(cfg):
    """A detector factory (``--detector fakes:oracle_factory``): the oracle as target and ACS model."""
    det = OracleDetector()
    return det, det


class _DiesOnce(OracleDetector):
    """The oracle, but the first call of the whole test (marker file absent) kills its process."""

    def __init__(self, marker: str):
        self.marker = marker
        super().__init__()

    def detect(self, frame):
        import os
        import signal
        from pathlib import Path

        if not Path(self.marker).exists():
            Path(self.marker).write_text("killed once")
            os.kill(os.getpid(), signal.SIGKILL)
        return super().detect(frame)


def dies_once_factory(cfg):
    """A detector factory whose worker process is killed mid-scene once (marker: $ASG_TEST_MARKER)."""
    import os

    det = _DiesOnce(os.environ["ASG_TEST_MARKER"])
    return det, det
