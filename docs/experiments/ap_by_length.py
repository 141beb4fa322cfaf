"""Where a detector's AP goes by vehicle length: recall at IoU 0.7 of the vehicles up to and over
``--long-m`` (detections scoring at least ``--min-score``), and AP with the long vehicles left out
(their ground truth, and the detections overlapping them by BEV IoU > 0.1), both yardsticks.

    ASG_DATA=<data root> python docs/experiments/ap_by_length.py FUSION [--set normal-val] [--long-m 6]

FUSION is any ``--fusion`` value (a shipped model or ``opencood:DIR``). Prints one JSON object.
"""
from __future__ import annotations

import argparse
import json

import numpy as np

from asg.datasets import scenes_of
from asg.evaluation import target_detector
from asg.objective.ap import ap_by_method
from asg.objective.iou import bev_iou_matrix
from asg.perception.data import Sample
from asg.perception.targets import resolve_target
from asg.sensors import load_lidar_spec, simulate_frame


def detected_frames(fusion: str, set_name: str) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """(boxes (K, 7), scores (K,), ground truth (M, 7)) of each frame of the set, ego frame."""
    detector, spec = target_detector(resolve_target(fusion)), load_lidar_spec()
    frames = []
    for scene in scenes_of(set_name):
        sample = Sample(scene.scene_id, simulate_frame(scene, spec))
        frames.append((*detector.detect(sample.frame), sample.gt_eval()))
    return frames


def by_length(frames, long_m: float, min_score: float) -> dict:
    found = {"short": [0, 0], "long": [0, 0]}
    without_long = []
    for boxes, scores, gt in frames:
        long = gt[:, 3] > long_m
        kept = boxes[scores >= min_score]
        hit = (bev_iou_matrix(kept, gt) >= 0.7).any(axis=0) if len(kept) and len(gt) else np.zeros(len(gt), bool)
        for name, mask in (("short", ~long), ("long", long)):
            found[name][0] += int(hit[mask].sum())
            found[name][1] += int(mask.sum())
        on_long = (bev_iou_matrix(boxes, gt[long]) > 0.1).any(axis=1) if len(boxes) and long.any() else np.zeros(len(boxes), bool)
        without_long.append((boxes[~on_long], scores[~on_long], gt[~long]))
    return {"recall_0.7": {k: {"found": f, "vehicles": n} for k, (f, n) in found.items()},
            "ap": ap_by_method(frames), "ap_without_long": ap_by_method(without_long)}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("fusion")
    p.add_argument("--set", default="normal-val")
    p.add_argument("--long-m", type=float, default=6.0)
    p.add_argument("--min-score", type=float, default=0.3)
    args = p.parse_args()
    result = by_length(detected_frames(args.fusion, args.set), args.long_m, args.min_score)
    print(json.dumps({"fusion": args.fusion, "set": args.set, "long_m": args.long_m, "min_score": args.min_score} | result))


if __name__ == "__main__":
    main()
