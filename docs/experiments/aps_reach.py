"""How far can moving three vehicles take AP? On a finished `asg bench paper` run (ACS-A + BO by default),
per scene: which ground-truth rows are the perturbed vehicles; recall at 0.3/0.5/0.7 of the moved
vehicles and of the rest, after ACS and at the end; and the pooled AP after ACS if the moved vehicles
simply vanished from the detections (their ground truth kept, as misses; nothing else changed).
usage: .venv/bin/python docs/experiments/aps_reach.py RUN_DIR   (e.g. runs/bench17/attfuse/attention-bo)
"""
import json
import sys
from pathlib import Path

import numpy as np

from asg.objective.ap import ap_at
from asg.objective.iou import bev_iou_matrix
from asg.perception.data import in_range
from asg.scene.scene import load_scene
from asg.sensors.frame import boxes_to_sensor, ground_truth
from asg.sensors.lidar_spec import load_lidar_spec
from asg.sensors.world import sensor_pose

THRESHOLDS = (0.3, 0.5, 0.7)


def matched_gt(boxes: np.ndarray, scores: np.ndarray, gt: np.ndarray, iou_threshold: float) -> np.ndarray:
    """(M,) bool: ground truth matched by the greedy score-order matching of asg.objective.ap."""
    taken = np.zeros(len(gt), dtype=bool)
    if not len(boxes) or not len(gt):
        return taken
    iou = bev_iou_matrix(boxes, gt)
    for i in np.argsort(-scores, kind="stable"):
        cand = np.where(taken, -1.0, iou[i])
        j = int(np.argmax(cand))
        if cand[j] >= iou_threshold:
            taken[j] = True
    return taken


def moved_rows(scene_path: Path, gt_ego: np.ndarray, perturbed: list[str], spec) -> np.ndarray:
    """(M,) bool over the stored ego-frame ground truth: rows of the perturbed vehicles."""
    scene = load_scene(scene_path)
    ids, gt_world = ground_truth(scene)
    gt_e = boxes_to_sensor(gt_world, sensor_pose(scene.ego, spec))
    keep = in_range(gt_e)
    if not np.allclose(gt_e[keep], gt_ego, atol=1e-4):
        raise SystemExit(f"{scene_path}: stored ground truth does not match the scene")
    return np.array([i in perturbed for i, k in zip(ids, keep) if k], dtype=bool)


def main(run_dir: Path) -> None:
    spec = load_lidar_spec("v2xp")
    summary = json.loads((run_dir / "summary.json").read_text())
    frames = {"after_acs": [], "final": [], "after_acs, moved vehicles vanished": []}
    counts = {}
    for s in summary["scenes"]:
        d = run_dir / "scenes" / s["scene_id"]
        det = np.load(d / "detections.npz")
        for stage in ("after_acs", "final"):
            boxes, scores, gt = det[f"{stage}_boxes"], det[f"{stage}_scores"], det[f"{stage}_gt"]
            frames[stage].append((boxes, scores, gt))
            moved = moved_rows(d / f"{stage}.yaml", gt, s["perturbed"], spec)
            for t in THRESHOLDS:
                hit = matched_gt(boxes, scores, gt, t)
                for group, rows in (("moved", moved), ("rest", ~moved)):
                    h, n = counts.get((stage, group, t), (0, 0))
                    counts[(stage, group, t)] = (h + int(hit[rows].sum()), n + int(rows.sum()))
            if stage == "after_acs":
                near = (bev_iou_matrix(boxes, gt[moved]).max(axis=1) >= 0.1) if moved.any() and len(boxes) \
                    else np.zeros(len(boxes), dtype=bool)
                frames["after_acs, moved vehicles vanished"].append((boxes[~near], scores[~near], gt))
    print(f"{len(summary['scenes'])} scenes; pooled AP % at 0.3 / 0.5 / 0.7")
    for name, f in frames.items():
        print(f"  {name}: " + " / ".join(f"{100 * v:.1f}" for v in ap_at(f).values()))
    print("recall % at 0.3 / 0.5 / 0.7 (matched / ground truth)")
    for stage in ("after_acs", "final"):
        for group in ("moved", "rest"):
            cells = [counts[(stage, group, t)] for t in THRESHOLDS]
            print(f"  {stage}, {group} ({cells[0][1]} vehicles): "
                  + " / ".join(f"{100 * h / max(n, 1):.1f}" for h, n in cells))


if __name__ == "__main__":
    main(Path(sys.argv[1]))
