"""What Where2comm's sparse messages cost: AP@0.3/0.5/0.7 under both yardsticks (ours: global sort;
the paper's: per frame) and the share of the collaborators' BEV cells sent, for several
``comm_threshold`` values (0: every cell, the network is then AttFuse's with Where2comm's weights),
beside the shipped AttFuse, on the same simulated frames; and the median time of a frame.

    .venv/bin/python docs/experiments/where2comm_threshold.py OUT.json [SET] [THRESHOLD ...]
    (default normal-val, thresholds 0 0.01 0.05 0.1)
"""
from __future__ import annotations

import json
import statistics
import sys
import time
from dataclasses import replace

from asg.datasets import scenes_of
from asg.evaluation import scored
from asg.perception import build_detector
from asg.perception.data import Sample
from asg.sensors import load_lidar_spec, simulate_frame


def main(out_path: str, set_name: str, thresholds: list[float]) -> None:
    import torch

    torch.set_num_threads(2)
    spec = load_lidar_spec()
    samples = [Sample(s.scene_id, simulate_frame(s, spec)) for s in scenes_of(set_name)]
    attfuse = build_detector("attfuse")
    detectors = [("attfuse", None, attfuse)]
    for t in thresholds:
        det = build_detector("where2comm")
        det = build_detector("where2comm", cfg=replace(det.cfg, comm_threshold=t))
        detectors.append(("where2comm", t, det))
    rows = []
    for name, threshold, det in detectors:
        frames, rates, times = [], [], []
        for s in samples:
            start = time.perf_counter()
            boxes, scores = det.detect(s.frame)
            times.append(time.perf_counter() - start)
            frames.append((boxes, scores, s.gt_eval()))
            rate = getattr(det.model, "last_comm_rate", None)
            if rate is not None:
                rates.append(rate)
        result = scored(frames)
        rows.append({"model": name, "comm_threshold": threshold, "frames": len(frames),
                     "ap": result["ap"], "ap_per_frame": result["ap_per_frame"],
                     "cells_sent": round(statistics.mean(rates), 4) if rates else None,
                     "ms_median": round(1e3 * statistics.median(times), 1)})
        print(json.dumps(rows[-1]), flush=True)
    with open(out_path, "w") as fh:
        json.dump({"set": set_name, "rows": rows}, fh, indent=1)


if __name__ == "__main__":
    args = sys.argv[1:]
    if not args:
        sys.exit(__doc__)
    main(args[0], args[1] if len(args) > 1 else "normal-val", [float(a) for a in args[2:]] or [0.0, 0.01, 0.05, 0.1])
