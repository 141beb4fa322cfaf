"""The OpenCOOD adapter's frame with its pillar net's layer as asg runs it (the max before the batch
norm, asg/perception/opencood/pillar_max.py) and as OpenCOOD ships it, alternating in one process,
ROUNDS rounds over FRAMES normal frames (3 sensing agents, two threads, OMP_WAIT_POLICY=ACTIVE as
asg sets it for OpenCOOD models); checks that both ways give the same boxes and scores to the bit.
Prints one JSON line.
usage: OMP_WAIT_POLICY=ACTIVE .venv/bin/python docs/experiments/opencood_pillar_max_time.py [ROUNDS] [FRAMES]
"""
import itertools
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import torch

from asg.datasets import scenes_of
from asg.perception import build_detector
from asg.perception.opencood.pillar_max import pfn_layer_type
from asg.scene.neighbours import with_nearest_collaborators
from asg.sensors import load_lidar_spec, simulate_frame

FOLDER = Path(__file__).resolve().parent / "opencood-attfuse-asg"


def main(rounds: int, frames_count: int) -> None:
    torch.set_num_threads(2)
    spec = load_lidar_spec()
    frames = [simulate_frame(with_nearest_collaborators(s, 2), spec)
              for s in itertools.islice(scenes_of("normal"), frames_count)]
    det = build_detector(f"opencood:{FOLDER}")
    layers = [m for m in det.model.modules() if isinstance(m, pfn_layer_type())]
    asgs = [layer.forward for layer in layers]

    def use(way: str) -> None:
        for layer, forward in zip(layers, asgs):
            if way == "asg":
                layer.forward = forward
            elif "forward" in vars(layer):
                del layer.forward  # the class's forward: OpenCOOD's own

    outputs, ms = {}, {"opencood": [], "asg": []}
    for way in ms:
        use(way)
        outputs[way] = [det.detect(f) for f in frames]  # also the warm-up
    for _ in range(rounds):
        for way in ms:
            use(way)
            t = time.perf_counter()
            for f in frames:
                det.detect(f)
            ms[way].append(round((time.perf_counter() - t) / len(frames) * 1e3, 1))
    same = all(np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
               for a, b in zip(outputs["opencood"], outputs["asg"]))
    print(json.dumps({"frames": frames_count, "rounds": rounds, "same_boxes_and_scores": same,
                      "boxes": sum(len(b) for b, _ in outputs["asg"]), "ms_a_frame": ms,
                      "median_ms": {k: statistics.median(v) for k, v in ms.items()}}))


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 5, int(sys.argv[2]) if len(sys.argv) > 2 else 16)
