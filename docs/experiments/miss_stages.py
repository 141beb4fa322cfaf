"""Where does the detector lose the visible vehicles it misses: in the network (no candidate box
near the vehicle passes the score threshold, or none fits it at IoU 0.7) or in the post-processing
(a candidate fits it at IoU 0.7, but rotated NMS suppresses it for a higher-scored worse box, or box
voting moves the kept box below 0.7)? For the visible vehicles (10+ fused LiDAR points) of a set,
moved by the attack and unmoved, the share at each stage, and for the vehicles whose best
candidate fits at IoU 0.5-0.7 how that candidate is off (centre along and across the vehicle,
yaw folded to [0, 90) deg, length and width) and how much of the vehicle's length its points
cover (their span along the vehicle over its length), beside the vehicles found.

    .venv/bin/python docs/experiments/miss_stages.py [SET] [MODEL ...]

SET: a built challenging set (default challenging-attfuse-val) or any set; MODEL: a shipped name
or NAME=weights.pt (default attfuse). The candidates are what ``postprocess`` hands to NMS (boxes
after refinement, scores after IoU rescoring, score threshold passed); IoU is the evaluation's
rotated BEV IoU.
"""
from __future__ import annotations

import json
import sys

import numpy as np

import asg.perception.model as model_module
from asg.datasets import data_root
from asg.objective.iou import bev_iou_matrix
from asg.perception.nms import rotated_nms
from ap_bootstrap import build_models  # this folder's
from moved_vehicles import found_at, frames_of, wrap_deg  # this folder's

MIN_POINTS = 10
IOU = 0.7
STAGES = ("found", "no candidate >= 0.5", "best candidate 0.5-0.7", "0.7 candidate suppressed by NMS",
          "0.7 candidate kept, lost in voting")


class CandidateTap:
    """Inside ``with CandidateTap() as tap``, the detector's ``select_boxes`` keeps what it was
    handed; ``tap.last()``: (boxes (N, 7), scores (N,)) of the last frame (empty if none passed)."""

    def __init__(self):
        self.calls: list[tuple[np.ndarray, np.ndarray]] = []
        self._inner = model_module.select_boxes

    def __call__(self, boxes, scores, cfg):
        self.calls.append((np.asarray(boxes, float).reshape(-1, 7), np.asarray(scores, float)))
        return self._inner(boxes, scores, cfg)

    def __enter__(self) -> "CandidateTap":
        model_module.select_boxes = self
        return self

    def __exit__(self, *exc) -> None:
        model_module.select_boxes = self._inner

    def detect(self, detector, frame):
        """``detector.detect(frame)``, keeping only this frame's candidates."""
        self.calls.clear()
        return detector.detect(frame)

    def last(self) -> tuple[np.ndarray, np.ndarray]:
        return self.calls[0] if self.calls else (np.zeros((0, 7)), np.zeros(0))


def stage_of(i: int, found: np.ndarray, cand_iou: np.ndarray, kept: np.ndarray) -> int:
    """The STAGES index of ground-truth vehicle ``i``: ``cand_iou`` (N, M) candidates x vehicles,
    ``kept`` (N,) bool: the candidate survived NMS."""
    if found[i]:
        return 0
    col = cand_iou[:, i] if cand_iou.size else np.zeros(0)
    if not len(col) or col.max() < 0.5:
        return 1
    if col.max() < IOU:
        return 2
    return 4 if (kept & (col >= IOU)).any() else 3


def errors_of(cand: np.ndarray, gt: np.ndarray) -> tuple[float, ...]:
    """How candidate box ``cand`` (7,) is off ``gt`` (7,): |along|, |across| (m, in the vehicle's
    frame), |yaw| (deg, a box and its reverse the same), length and width (m, candidate - truth)."""
    c, s = np.cos(gt[6]), np.sin(gt[6])
    dx, dy = cand[0] - gt[0], cand[1] - gt[1]
    return (abs(c * dx + s * dy), abs(-s * dx + c * dy), abs(wrap_deg(cand[6] - gt[6])), cand[3] - gt[3],
            cand[4] - gt[4])


def along_cover(points: np.ndarray, box: np.ndarray, margin_m: float = 0.02) -> float:
    """The span of the ``points`` (N, >=3; the box's frame) inside ``box`` (7,) along its length,
    over its length: 1 when both ends are seen, 0 with fewer than two points."""
    x, y, z, length, width, height, yaw = box
    q = points[:, :3] - (x, y, z)
    c, s = np.cos(yaw), np.sin(yaw)
    lx, ly = c * q[:, 0] + s * q[:, 1], -s * q[:, 0] + c * q[:, 1]
    inside = (np.abs(lx) <= length / 2 + margin_m) & (np.abs(ly) <= width / 2 + margin_m) & (np.abs(q[:, 2]) <= height / 2 + margin_m)
    return float(np.ptp(lx[inside]) / length) if inside.sum() >= 2 else 0.0


def rows_of(set_name: str, detector, cfg) -> np.ndarray:
    """(V, 8) per visible vehicle: moved (0/1), stage (index into STAGES), errors_of its best
    candidate (nan without one), along_cover of the fused points."""
    summary_path = data_root() / set_name / "run" / "summary.json"
    summary = json.loads(summary_path.read_text()) if summary_path.is_file() else {"scenes": []}
    moved = {e["scene_id"]: set(map(str, e.get("moved") or [])) for e in summary["scenes"]}
    rows = []
    with CandidateTap() as tap:
        for scene_id, frame, gt, points, ids in frames_of(set_name):
            boxes, scores = tap.detect(detector, frame)
            cand, cand_scores = tap.last()
            found = found_at(boxes, scores, gt, IOU)
            fused = np.concatenate(frame.clouds_in_frame_of(frame.ego_id))
            cand_iou = bev_iou_matrix(cand, gt) if len(cand) and len(gt) else np.zeros((len(cand), len(gt)))
            kept = np.zeros(len(cand), bool)
            if len(cand):
                kept[rotated_nms(cand, cand_scores, cfg.nms_iou, cfg.max_detections)] = True
            for i, vid in enumerate(ids):
                if points[i] >= MIN_POINTS:
                    err = errors_of(cand[cand_iou[:, i].argmax()], gt[i]) if len(cand) else (np.nan,) * 5
                    rows.append((str(vid) in moved.get(scene_id, set()), stage_of(i, found, cand_iou, kept), *err,
                                 along_cover(fused, gt[i])))
    return np.array(rows, float).reshape(-1, 8)


def main(set_name: str = "challenging-attfuse-val", *models: str) -> None:
    for name, detector in build_models(models or ["attfuse"]).items():
        r = rows_of(set_name, detector, detector.cfg)
        print(f"\n{set_name}, {name}: visible vehicles (>= {MIN_POINTS} points), % at each stage")
        print("| stage | " + " | ".join(f"{label} (n={int((r[:, 0] == m).sum())})"
                                       for m, label in ((0, "unmoved"), (1, "moved")) if (r[:, 0] == m).any()) + " |")
        for s, stage in enumerate(STAGES):
            cells = [f"{100 * (r[r[:, 0] == m, 1] == s).mean():.1f}" for m in (0, 1) if (r[:, 0] == m).any()]
            print(f"| {stage} | " + " | ".join(cells) + " |")
        print("best candidate at IoU 0.5-0.7, median |along|, |across| (m), |yaw| (deg), length, width error (m):")
        for m, label in ((0, "unmoved"), (1, "moved")):
            s = r[(r[:, 0] == m) & (r[:, 1] == 2)]
            if len(s):
                print(f"  {label} (n={len(s)}): " + ", ".join(f"{v:.2f}" for v in np.median(s[:, 2:7], axis=0)))
        print("share of the length the points cover, median (share of vehicles under half):")
        for m, label in ((0, "unmoved"), (1, "moved")):
            cells = [f"{STAGES[k]} {np.median(c):.2f} ({100 * (c < 0.5).mean():.0f} %)"
                     for k in range(len(STAGES)) if len(c := r[(r[:, 0] == m) & (r[:, 1] == k), 7])]
            if cells:
                print(f"  {label}: " + "; ".join(cells))


if __name__ == "__main__":
    main(*sys.argv[1:])
