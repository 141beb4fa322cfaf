"""Why are the vehicles the attack moved so hard to find? Recall at IoU 0.7 of the visible vehicles
(10+ fused LiDAR points) of a challenging set, moved and unmoved, by how far the attack turned the
vehicle off its lane (|delta yaw|), by the distance to the nearest other vehicle, and by length,
with the yaw error of the nearest detection against the vehicle's true yaw and against its lane's.

    .venv/bin/python docs/experiments/moved_vehicles.py [SET] [MODEL]

SET: a built challenging set (default challenging-attfuse-val); MODEL: a shipped name or
NAME=weights.pt (default attfuse). Prints one table per split.
"""
from __future__ import annotations

import json
import sys

import numpy as np

from asg.datasets import data_root, scenes_of
from asg.objective.ap import greedy_match
from asg.perception.data import Sample, in_range
from asg.sensors import load_lidar_spec, simulate_frame
from ap_bootstrap import build_models  # this folder's

MIN_POINTS = 10


def wrap_deg(a: np.ndarray) -> np.ndarray:
    """Angles (rad) as degrees in [-90, 90): a box's heading and its reverse are the same box."""
    return (np.degrees(a) + 90.0) % 180.0 - 90.0


def frames_of(set_name: str):
    """Per scene of the set: (scene id, frame, ground truth in range (M, 7) in the ego frame, fused
    LiDAR points in each of those boxes (M,), their vehicle ids (M,))."""
    spec = load_lidar_spec()
    for scene in scenes_of(set_name):
        sample = Sample(scene.scene_id, simulate_frame(scene, spec))
        keep = in_range(sample.frame.ego_boxes)
        yield (scene.scene_id, sample.frame, sample.gt_eval(), sample.frame.points_in_boxes()["fused"][keep],
               np.asarray(sample.frame.gt_ids)[keep])


def found_at(boxes: np.ndarray, scores: np.ndarray, gt: np.ndarray, iou: float) -> np.ndarray:
    """(M,) bool: the ground-truth boxes the detections (K, 7) with ``scores`` (K,) find at ``iou``."""
    match = greedy_match(boxes, scores, gt, iou)
    found = np.zeros(len(gt), bool)
    found[match[match >= 0]] = True
    return found


def rows_of(set_name: str, detector) -> np.ndarray:
    """One row per visible vehicle: moved, found@0.7, nearest-vehicle distance (m), length (m),
    |delta yaw| of the attack (deg, 0 if unmoved), |det - true yaw|, |det - lane yaw| (deg) of the
    nearest detection (nan without one)."""
    summary = json.loads((data_root() / set_name / "run" / "summary.json").read_text())
    moved = {e["scene_id"]: dict(zip(e.get("moved") or [], e.get("delta") or [])) for e in summary["scenes"]}
    rows = []
    for scene_id, frame, gt, points, ids in frames_of(set_name):
        boxes, scores = detector.detect(frame)
        boxes = np.asarray(boxes).reshape(-1, 7)
        found = found_at(boxes, scores, gt, 0.7)
        gap = np.linalg.norm(gt[:, None, :2] - gt[None, :, :2], axis=2) + np.eye(len(gt)) * 1e9
        nearest = gap.min(1) if len(gt) > 1 else np.full(len(gt), np.inf)
        deltas = moved.get(scene_id, {})
        for i, vid in enumerate(ids):
            if points[i] < MIN_POINTS:
                continue
            d_yaw = deltas[str(vid)][2] if str(vid) in deltas else 0.0
            err_true = err_lane = np.nan
            if len(boxes):
                j = int(np.linalg.norm(boxes[:, :2] - gt[i, :2], axis=1).argmin())
                err_true = abs(wrap_deg(boxes[j, 6] - gt[i, 6]))
                err_lane = abs(wrap_deg(boxes[j, 6] - (gt[i, 6] - d_yaw)))
            rows.append((str(vid) in deltas, found[i], nearest[i], gt[i, 3], abs(np.degrees(d_yaw)), err_true, err_lane))
    return np.array(rows, float).reshape(-1, 7)


def table(r: np.ndarray, column: int, edges: tuple, label: str) -> None:
    print(f"\n{label} | unmoved: n, recall@0.7 (%) | moved: n, recall@0.7 (%), median |det - true yaw|, |det - lane yaw| (deg)")
    for lo, hi in zip(edges[:-1], edges[1:]):
        cells = []
        for m in (0, 1):
            s = r[(r[:, 0] == m) & (r[:, column] >= lo) & (r[:, column] < hi)]
            if not len(s):
                cells.append("-")
            elif m == 0:
                cells.append(f"{len(s)}, {100 * s[:, 1].mean():.1f}")
            else:
                cells.append(f"{len(s)}, {100 * s[:, 1].mean():.1f}, {np.nanmedian(s[:, 5]):.1f}, {np.nanmedian(s[:, 6]):.1f}")
        print(f"{lo:g}-{hi:g} | " + " | ".join(cells))


def main(set_name: str = "challenging-attfuse-val", model: str = "attfuse") -> None:
    detector = next(iter(build_models([model]).values()))
    r = rows_of(set_name, detector)
    table(r, 4, (0, 10, 20, 30, 46), "|delta yaw| (deg)")
    table(r, 2, (0, 4, 5, 6, 8, 12, 1e9), "nearest vehicle (m)")
    table(r, 3, (0, 5.5, 8, 30), "length (m)")


if __name__ == "__main__":
    main(*sys.argv[1:])
