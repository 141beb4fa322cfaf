"""How many ground-truth vehicles can a detector see at all? Per set: vehicles within the evaluation
range, the share with no fused LiDAR point (no detector can find them: they cap recall), with fewer
than 10, and the median points per vehicle; what the attack changes, and so how much fine-tuning
can win back.
usage: .venv/bin/python docs/experiments/visibility_ceiling.py SET [SET ...]
       (e.g. normal-val challenging-attfuse-val heuristic holdout)
"""
import sys

import numpy as np

from asg.perception.data import points_in_range_boxes
from asg.datasets import scenes_of
from asg.sensors import load_lidar_spec, simulate_frame


def main(sets: list[str]) -> None:
    spec = load_lidar_spec("v2xp")
    print(f"{'set':28s} {'frames':>6s} {'vehicles':>8s} {'0 points':>9s} {'<10 points':>10s} {'median pts':>10s}")
    for name in sets:
        counts, frames = [], 0
        for scene in scenes_of(name):
            counts.append(points_in_range_boxes(simulate_frame(scene, spec)))
            frames += 1
        n = np.concatenate(counts) if counts else np.zeros(0, int)
        print(f"{name:28s} {frames:6d} {len(n):8d} {100 * np.mean(n == 0):8.1f}% {100 * np.mean(n < 10):9.1f}% "
              f"{np.median(n):10.0f}")


if __name__ == "__main__":
    main(sys.argv[1:] or ["normal-val", "challenging-attfuse-val"])
