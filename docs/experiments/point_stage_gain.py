"""What the point stage gives each shipped detector: AP@0.3/0.5/0.7 under both yardsticks (ours:
global sort; the paper's: per frame) on each set, with the stage (as shipped) and without it
(`point_stage: false`), the same simulated frames for both; and the mean IoU of the boxes that
overlap a vehicle. Also the time a frame takes each way.

    .venv/bin/python docs/experiments/point_stage_gain.py OUT.json [SET ...]   (default normal-val heuristic)
"""
from __future__ import annotations

import json
import statistics
import sys
import time
from dataclasses import replace

from asg.datasets import scenes_of
from asg.perception import build_detector
from asg.perception.data import Sample
from asg.sensors import load_lidar_spec, simulate_frame
from asg.evaluation import scored
from asg.training.point_stage_fit import mean_iou

MODELS = ("none", "late", "early", "attfuse", "attfuse-ft", "fcooper")


def main(out_path: str, sets: list[str]) -> None:
    import torch

    torch.set_num_threads(2)
    spec = load_lidar_spec()
    result = {}
    for set_name in sets:
        samples = [Sample(s.scene_id, simulate_frame(s, spec)) for s in scenes_of(set_name)]
        for fusion in MODELS:
            shipped = build_detector(fusion)
            plain = build_detector(fusion, cfg=replace(shipped.cfg, point_stage=False))
            row = {}
            for arm, det in (("stage", shipped), ("no stage", plain)):
                frames, times = [], []
                for s in samples:
                    t = time.perf_counter()
                    boxes, scores = det.detect(s.frame)
                    times.append(time.perf_counter() - t)
                    frames.append((boxes, scores, s.gt_eval()))
                row[arm] = {**scored(frames), "mean_iou_matched": mean_iou(frames),
                            "ms_per_frame_median": round(1e3 * statistics.median(times), 1)}
            result.setdefault(set_name, {})[fusion] = row
            print(set_name, fusion, {arm: (round(100 * r["ap"]["0.7"], 1), round(100 * r["ap_per_frame"]["0.7"], 1),
                                           r["mean_iou_matched"], r["ms_per_frame_median"]) for arm, r in row.items()},
                  flush=True)
    with open(out_path, "w") as fh:
        json.dump(result, fh, indent=1)


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2:] or ["normal-val", "heuristic"])
