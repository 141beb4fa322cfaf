"""The point stage's gathering of each box's points (asg.perception.point_stage.box_points) on the
boxes AttFuse finds before its stage: median ms a frame over FRAMES normal frames, ROUNDS rounds,
one thread. Run with PYTHONPATH set to a checkout of the commit measured (as speed_ab.sh does) to
compare two commits on the same frames.
usage: PYTHONPATH=TREE .venv/bin/python docs/experiments/box_points_time.py [FRAMES] [ROUNDS]
"""
import itertools
import json
import statistics
import sys
import time

import torch

from asg.datasets import scenes_of
from asg.executors import apply_threads
from asg.perception import build_detector
from asg.perception.point_stage import box_points
from asg.scene.neighbours import with_nearest_collaborators
from asg.sensors import load_lidar_spec, simulate_frame


def main(count: int, rounds: int) -> None:
    apply_threads(1)
    spec = load_lidar_spec()
    det = build_detector("attfuse")
    stage, det.point_stage = det.point_stage, None  # detect gives the boxes the stage would refine
    cases = []
    for scene in itertools.islice(scenes_of("normal"), count):
        frame = simulate_frame(with_nearest_collaborators(scene, 2), spec)
        boxes, _ = det.detect(frame)
        cases.append((boxes, det.seen_cloud(frame)))
    det.point_stage = stage
    for boxes, cloud in cases:
        box_points(boxes, cloud)
    times = []
    for _ in range(rounds):
        t = time.perf_counter()
        for boxes, cloud in cases:
            box_points(boxes, cloud)
        times.append((time.perf_counter() - t) / len(cases) * 1e3)
    print(json.dumps({"frames": count, "rounds": rounds, "boxes_a_frame": round(statistics.mean(len(b) for b, _ in cases), 1),
                      "ms_a_frame": round(statistics.median(times), 2), "torch": torch.__version__}))


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 40, int(sys.argv[2]) if len(sys.argv) > 2 else 5)
