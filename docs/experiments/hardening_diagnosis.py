"""Where does a fine-tuned detector gain or lose? Recall by visibility and AP over the vehicles
that can be found, for several AttFuse weights on the same rendered frames.

Per set, each frame is rendered once; every model detects it. Each ground-truth vehicle in range
falls in a visibility bucket by its fused LiDAR points (0, 1-9, 10-49, 50+); recall per bucket is
the share matched at IoU 0.7 (and 0.5) by the greedy matching AP uses. "AP@0.7 >= k points" scores
only the vehicles with at least k points: a detection matched to a vehicle with fewer is neither
a true nor a false positive ("don't care", as KITTI's ignored boxes), so the gap between the full
AP and it is what vehicles that no LiDAR ray (or too few) reached cost. On a challenging set, recall
is also split by whether the attack moved the vehicle ("moved": the run folder's summary).

usage: .venv/bin/python docs/experiments/hardening_diagnosis.py OUT.json SETS MODEL [MODEL ...]
  SETS: comma-separated (e.g. normal-val,challenging-attfuse-val,heuristic)
  MODEL: a shipped AttFuse name (attfuse, attfuse-ft) or NAME=path/to/weights.pt (AttFuse network)
"""
import json
import sys

import numpy as np

from asg.objective.ap import ap_from_matches, greedy_match
from asg.perception.data import Sample
from asg.datasets import scenes_of
from asg.sensors import load_lidar_spec, simulate_frame
from ap_bootstrap import build_models  # this folder's

BUCKETS = ((0, 0), (1, 9), (10, 49), (50, None))
THRESHOLDS = (0.5, 0.7)
MIN_POINTS = (1, 10)


def bucket_name(lo: int, hi: int | None) -> str:
    return f"{lo}+" if hi is None else (f"{lo}" if lo == hi else f"{lo}-{hi}")


def diagnose(set_name: str, dets: dict) -> dict:
    spec = load_lidar_spec("v2xp")
    points = []  # per frame (M,) fused points of each vehicle in range
    moved_flags = []  # per frame (M,) bool: did the attack move the vehicle (challenging sets)
    moved_ids = _moved_by_scene(set_name)
    per_model = {m: {t: [] for t in THRESHOLDS} for m in dets}  # per frame (scores, found gt index)
    for scene in scenes_of(set_name):
        sample = Sample(scene.scene_id, simulate_frame(scene, spec))
        gt = sample.gt_eval()
        mask = _in_range_mask(sample)
        points.append(sample.frame.points_in_boxes()["fused"][mask])
        ids = np.asarray(sample.frame.gt_ids)[mask]
        moved_flags.append(np.isin(ids, list(moved_ids.get(scene.scene_id, ()))))
        assert len(points[-1]) == len(gt)
        for m, det in dets.items():
            boxes, scores = det.detect(sample.frame)
            for t in THRESHOLDS:
                per_model[m][t].append((np.asarray(scores, float), greedy_match(boxes, scores, gt, t)))
    n_points = np.concatenate(points) if points else np.zeros(0, int)
    moved_all = np.concatenate(moved_flags) if moved_flags else np.zeros(0, bool)
    result = {"frames": len(points), "vehicles": int(len(n_points)), "moved": int(moved_all.sum()),
              "buckets": {bucket_name(lo, hi): int(np.sum(_in_bucket(n_points, lo, hi))) for lo, hi in BUCKETS},
              "models": {}}
    for m in dets:
        row = {}
        for t in THRESHOLDS:
            found = np.zeros(len(n_points), bool)
            offset = 0
            for (scores, match), pts in zip(per_model[m][t], points):
                found[offset + match[match >= 0]] = True
                offset += len(pts)
            row[f"recall@{t:g}"] = {bucket_name(lo, hi): _share(found, _in_bucket(n_points, lo, hi)) for lo, hi in BUCKETS}
            if moved_ids:
                moved = np.concatenate(moved_flags)
                row[f"recall@{t:g}_moved"] = {bucket_name(lo, hi): _share(found, _in_bucket(n_points, lo, hi) & moved)
                                              for lo, hi in BUCKETS}
                row[f"recall@{t:g}_unmoved"] = {bucket_name(lo, hi): _share(found, _in_bucket(n_points, lo, hi) & ~moved)
                                                for lo, hi in BUCKETS}
            row[f"ap@{t:g}"] = round(100 * ap_from_matches([s for s, _ in per_model[m][t]],
                                                           [mt >= 0 for _, mt in per_model[m][t]], len(n_points)), 2)
            for k in MIN_POINTS:
                row[f"ap@{t:g}_min{k}"] = _ap_ignoring(per_model[m][t], points, k)
        result["models"][m] = row
    return result


def _moved_by_scene(set_name: str) -> dict[str, list[str]]:
    """{scene id: ids of the vehicles the attack moved} of a built challenging set, else {}."""
    from asg.datasets import data_root

    summary = data_root() / set_name / "run" / "summary.json"
    if not set_name.startswith("challenging-") or not summary.is_file():
        return {}
    return {e["scene_id"]: list(e.get("moved") or []) for e in json.loads(summary.read_text())["scenes"]}


def _in_range_mask(sample: Sample) -> np.ndarray:
    from asg.perception.data import in_range

    return in_range(sample.frame.ego_boxes)


def _in_bucket(n: np.ndarray, lo: int, hi: int | None) -> np.ndarray:
    return (n >= lo) & (n <= hi) if hi is not None else n >= lo


def _share(found: np.ndarray, mask: np.ndarray) -> float | None:
    return round(100 * float(found[mask].mean()), 1) if mask.any() else None


def _ap_ignoring(frames: list, points: list, k: int) -> float:
    """AP over the vehicles with at least ``k`` points; detections of the others dropped."""
    scores, tps, n_gt = [], [], 0
    for (s, match), pts in zip(frames, points):
        kept = pts >= k
        n_gt += int(kept.sum())
        drop = (match >= 0) & ~kept[np.maximum(match, 0)]
        scores.append(s[~drop])
        tps.append(match[~drop] >= 0)
    return round(100 * ap_from_matches(scores, tps, n_gt), 2)


def main(out: str, sets: str, models: list[str]) -> None:
    dets = build_models(models)
    report = {s: diagnose(s, dets) for s in sets.split(",")}
    with open(out, "w") as f:
        json.dump(report, f, indent=1)
    for s, r in report.items():
        print(f"{s}: {r['frames']} frames, {r['vehicles']} vehicles, by points {r['buckets']}")
        for m, row in r["models"].items():
            print(f"  {m:14s} AP@0.7 {row['ap@0.7']:5.1f} (>=1 pt {row['ap@0.7_min1']:5.1f}, >=10 pts "
                  f"{row['ap@0.7_min10']:5.1f})  recall@0.7 by bucket {row['recall@0.7']}  recall@0.5 {row['recall@0.5']}")
            if "recall@0.7_moved" in row:
                print(f"  {'':14s} moved ({r['moved']}): recall@0.7 {row['recall@0.7_moved']} @0.5 {row['recall@0.5_moved']}; "
                      f"unmoved: recall@0.7 {row['recall@0.7_unmoved']}")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2], sys.argv[3:])
