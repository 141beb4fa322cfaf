"""A toy cooperative detector: fuse every agent's cloud into the ego frame, drop the ground, put
the points on a 2 m grid and call every cell with enough points a car (4.5 x 1.9 x 1.6 m, yaw 0).
It only shows the plugin protocol of asg (docs/plugins.md); it is not a good detector."""
import numpy as np

CELL_M = 2.0
MIN_POINTS = 8


class ToyDetector:
    def detect(self, frame):
        """(boxes (K, 7) in the ego sensor frame, scores (K,)) from ``frame`` (asg's CooperativeInput)."""
        to_ego = np.linalg.inv(frame.poses[frame.ego_id])
        fused = []
        for agent in frame.agent_ids:
            xyz1 = np.c_[frame.clouds[agent][:, :3], np.ones(len(frame.clouds[agent]))]
            fused.append((to_ego @ frame.poses[agent] @ xyz1.T).T[:, :3])
        pts = np.vstack(fused)
        ground_z = np.percentile(pts[:, 2], 5)
        pts = pts[(pts[:, 2] > ground_z + 0.3) & (pts[:, 2] < ground_z + 2.5)]
        cells, counts = np.unique(np.floor(pts[:, :2] / CELL_M).astype(int), axis=0, return_counts=True)
        keep = counts >= MIN_POINTS
        centres = (cells[keep] + 0.5) * CELL_M
        boxes = np.c_[centres, np.full(len(centres), ground_z + 0.8), np.tile([4.5, 1.9, 1.6, 0.0], (len(centres), 1))]
        return boxes, np.clip(counts[keep] / 100.0, 0.05, 1.0)

    def attention(self, frame):
        """Each agent's share of the points: what the collaborator search reads as attention."""
        n = {a: float(len(frame.clouds[a])) for a in frame.agent_ids}
        total = sum(n.values()) or 1.0
        return {a: v / total for a, v in n.items()}


class _BadShape(ToyDetector):
    def detect(self, frame):
        boxes, scores = super().detect(frame)
        return boxes[:, :5], scores


class _NaN(ToyDetector):
    def detect(self, frame):
        boxes, scores = super().detect(frame)
        boxes[:, 0] = np.nan
        return boxes, scores


def make():
    return ToyDetector()


def make_bad_shape():
    return _BadShape()


def make_nan():
    return _NaN()
