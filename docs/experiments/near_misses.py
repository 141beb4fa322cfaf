"""How close do the final boxes come to the vehicles they miss? For the visible vehicles (10+ fused
LiDAR points) of a set, moved by the attack and unmoved, the share found at IoU 0.7, the near misses
(the best final box overlaps the vehicle by 0.5-0.7 in BEV IoU: a box is there but not tight) and
the rest, for a detector with its point stage (as shipped) and without it. Unlike miss_stages.py,
which taps the candidates before NMS, this scores the boxes the detector returns.

    .venv/bin/python docs/experiments/near_misses.py SET [MODEL [WEIGHTS]]
    (MODEL default attfuse; WEIGHTS: other weights of MODEL's network, e.g. a hardening round's)
"""
from __future__ import annotations

import json
import sys
from dataclasses import replace

import numpy as np

from asg.datasets import data_root
from asg.objective.iou import bev_iou_matrix
from asg.perception import build_detector
from moved_vehicles import MIN_POINTS, found_at, frames_of  # this folder's


def shares(set_name: str, model: str, cfg=None, weights_file: str | None = None) -> dict:
    """The shares of ``model`` (its shipped weights and settings, or ``cfg`` and ``weights_file``)
    with its point stage and without it: {"stage" | "no stage": {"moved" | "unmoved": {...}}}."""
    summary_path = data_root() / set_name / "run" / "summary.json"
    moved = ({e["scene_id"]: set(e.get("moved") or []) for e in json.loads(summary_path.read_text())["scenes"]}
             if summary_path.is_file() else {})
    shipped = build_detector(model, cfg=cfg, weights_file=weights_file)
    detectors = {"stage": shipped, "no stage": build_detector(model, cfg=replace(shipped.cfg, point_stage=False),
                                                               weights_file=weights_file)}
    counts = {arm: {kind: np.zeros(3, int) for kind in ("moved", "unmoved")} for arm in detectors}
    for scene_id, frame, gt, points, ids in frames_of(set_name):
        for arm, det in detectors.items():
            boxes, scores = det.detect(frame)
            boxes = np.asarray(boxes).reshape(-1, 7)
            found = found_at(boxes, scores, gt, 0.7)
            best = bev_iou_matrix(gt, boxes).max(axis=1) if len(boxes) and len(gt) else np.zeros(len(gt))
            for i, vid in enumerate(ids):
                if points[i] < MIN_POINTS:
                    continue
                kind = "moved" if str(vid) in moved.get(scene_id, set()) else "unmoved"
                stage = 0 if found[i] else (1 if best[i] >= 0.5 else 2)
                counts[arm][kind][stage] += 1
    return {arm: {kind: {"vehicles": int(c.sum()), "found_pct": round(100 * c[0] / max(c.sum(), 1), 1),
                         "near_miss_pct": round(100 * c[1] / max(c.sum(), 1), 1),
                         "missed_pct": round(100 * c[2] / max(c.sum(), 1), 1)}
                  for kind, c in by_kind.items()} for arm, by_kind in counts.items()}


if __name__ == "__main__":
    print(json.dumps(shares(sys.argv[1], sys.argv[2] if len(sys.argv) > 2 else "attfuse",
                            weights_file=sys.argv[3] if len(sys.argv) > 3 else None), indent=1))
