"""One round of the speed A/B: run with PYTHONPATH set to a checkout of the commit measured, so the
same script measures the code before and after (docs/experiments/speed_ab.sh alternates them).
Prints JSON: seconds a scene of AttFuse + ACS-A + BO-50 and + GA-50 in one process on two threads
(``asg bench generate``'s setting: what that commit's generator does with them), and each shipped
model's and the OpenCOOD folder's median ms a frame (``asg bench detect``'s frames and repeats;
not with ``--scenes-only``).
usage: PYTHONPATH=TREE .venv/bin/python docs/experiments/speed_ab.py [SCENES] [--scenes-only]
"""
import inspect
import itertools
import json
import statistics
import sys
import time
from pathlib import Path

import asg  # first: it sets how OpenMP's threads wait, read when torch loads
import torch
from asg.benchmarks.detect import models
from asg.datasets import scenes_of
from asg.generator.config import load_generate_config
from asg.generator.pipeline import Generator
from asg.perception import build_detector
from asg.scene.neighbours import with_nearest_collaborators
from asg.sensors import load_lidar_spec, simulate_frame

OPENCOOD = Path(__file__).resolve().parent / "opencood-attfuse-asg"


def median_ms(call, items, repeats: int) -> float:
    """Median ms of ``call(item)`` over ``repeats`` rounds of ``items``, after one warm-up call
    (``asg bench detect``'s way)."""
    call(items[0])
    times = []
    for _ in range(repeats):
        for item in items:
            t = time.perf_counter()
            call(item)
            times.append(time.perf_counter() - t)
    return round(statistics.median(times) * 1e3, 1)


def generate_s(search: str, scenes: int) -> float:
    cfg = load_generate_config(fusion="attfuse", search=search, acs="attention", budget=50)
    det = build_detector("attfuse")
    takes = "candidate_threads" in inspect.signature(Generator.__init__).parameters
    gen = Generator(cfg, det, det, **({"candidate_threads": torch.get_num_threads()} if takes else {}))
    seconds = []
    for scene in itertools.islice(scenes_of("normal"), scenes):
        t = time.perf_counter()
        gen.attack(scene, 1)
        seconds.append(time.perf_counter() - t)
    return round(statistics.median(seconds), 2)


def main(scenes: int, frames: bool = True) -> None:
    torch.set_num_threads(2)
    out = {"tree": str(Path(asg.__file__).parent.parent), "threads": torch.get_num_threads(),
           "generate_bo_s": generate_s("bo", scenes), "generate_ga_s": generate_s("ga", scenes)}
    if not frames:
        print(json.dumps(out))
        return
    spec = load_lidar_spec()
    coop = [simulate_frame(with_nearest_collaborators(s, 2), spec) for s in itertools.islice(scenes_of("normal"), 10)]
    for name in models() + [f"opencood:{OPENCOOD}"]:
        frames = coop if not name.startswith("opencood") else coop[:5]
        label = "opencood-attfuse-asg" if name.startswith("opencood") else name
        out[f"{label}_ms"] = median_ms(build_detector(name).detect, frames, 3)
    print(json.dumps(out))


if __name__ == "__main__":
    args = [a for a in sys.argv[1:] if a != "--scenes-only"]
    main(int(args[0]) if args else 5, frames="--scenes-only" not in sys.argv[1:])
