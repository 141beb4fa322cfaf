"""Reduced precision measured: AttFuse with its network after the first backbone stage (the fusion,
the later stages and the upsampling, the head) under torch's CPU autocast to bfloat16, against
float32 as asg runs it. Prints one JSON line: AP on normal-val (both yardsticks) each way, and ms a
frame each way (two threads, ROUNDS alternating rounds over 16 normal frames). The pillar net and
the first stage (scatter and index kernels that autocast does not take) and the point stage stay
float32. The issue's rule for a reduced-precision path: AP unchanged to 0.1 point on normal-val.
usage: .venv/bin/python docs/experiments/bf16_ap.py [ROUNDS]
"""
import itertools
import json
import statistics
import sys
import time

import torch

from asg.datasets import scenes_of
from asg.evaluation import evaluate_detector
from asg.executors import apply_threads
from asg.perception import build_detector
from asg.scene.neighbours import with_nearest_collaborators
from asg.sensors import load_lidar_spec, simulate_frame


def in_bf16(fn):
    """``fn`` under CPU autocast to bfloat16, its tensor outputs back to float32."""
    def run(*args, **kwargs):
        with torch.autocast("cpu", dtype=torch.bfloat16):
            out = fn(*args, **kwargs)
        if isinstance(out, tuple):
            return tuple(o.float() if torch.is_tensor(o) and o.is_floating_point() else o for o in out)
        return out.float()
    return run


def set_precision(det, bf16: bool) -> None:
    model = det.model
    for part, name in ((model.fusion, "forward"), (model.backbone, "after_first_stage"), (model.head, "forward")):
        if name in vars(part):
            delattr(part, name)
        if bf16:
            setattr(part, name, in_bf16(getattr(part, name)))


def main(rounds: int) -> None:
    apply_threads(2)
    det = build_detector("attfuse")
    out = {"bf16_supported": torch.ops.mkldnn._is_mkldnn_bf16_supported(), "ap": {}, "ms_a_frame": {}}
    for way in ("float32", "bfloat16"):
        set_precision(det, way == "bfloat16")
        out["ap"][way] = evaluate_detector(det, scenes_of("normal-val"))
    spec = load_lidar_spec()
    frames = [simulate_frame(with_nearest_collaborators(s, 2), spec) for s in itertools.islice(scenes_of("normal"), 16)]
    ms = {"float32": [], "bfloat16": []}
    for _ in range(rounds):
        for way in ms:
            set_precision(det, way == "bfloat16")
            det.detect(frames[0])
            t = time.perf_counter()
            for f in frames:
                det.detect(f)
            ms[way].append(round((time.perf_counter() - t) / len(frames) * 1e3, 1))
    out["ms_a_frame"] = ms
    out["median_ms"] = {k: statistics.median(v) for k, v in ms.items()}
    print(json.dumps(out))


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 3)
