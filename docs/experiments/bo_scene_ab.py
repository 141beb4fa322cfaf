"""One side of the BO scene A/B: run with PYTHONPATH set to a checkout of the commit measured
(`docs/experiments/speed_ab.sh OLD ROUNDS OUT.jsonl docs/experiments/bo_scene_ab.py` alternates
two). Prints JSON: the tree, the median seconds a scene of
AttFuse + ACS-A + BO-50 over SCENES scenes of `normal` after a warm-up one (one process, two
threads: `asg bench generate`'s setting), the median of the optimiser's ask and tell time a scene,
and a digest of every search history (the two sides must agree on it).
usage: PYTHONPATH=TREE .venv/bin/python docs/experiments/bo_scene_ab.py [SCENES]
"""
import hashlib
import itertools
import json
import statistics
import sys
import time
from pathlib import Path

import asg  # first: it sets how OpenMP's threads wait, read when torch loads
import numpy as np
import torch
from asg.datasets import scenes_of
from asg.generator.config import load_generate_config
from asg.generator.pipeline import Generator
from asg.perception import build_detector


def main(count: int) -> None:
    torch.set_num_threads(2)
    cfg = load_generate_config(fusion="attfuse", search="bo", acs="attention", budget=50)
    det = build_detector("attfuse")
    gen = Generator(cfg, det, det, candidate_threads=2)
    scenes = list(itertools.islice(scenes_of("normal"), count + 1))
    gen.attack(scenes[0], 1)  # warm-up: lazy imports, compiled kernels
    seconds, optimizer, digest = [], [], hashlib.sha256()
    for scene in scenes[1:]:
        t = time.perf_counter()
        result = gen.attack(scene, 1)
        seconds.append(time.perf_counter() - t)
        optimizer.append(sum(result.bo_overhead_s))
        digest.update(np.array([e.loss for e in result.history]).tobytes())
        digest.update(np.array([e.x for e in result.history]).tobytes())
    print(json.dumps({"tree": str(Path(asg.__file__).parent.parent), "scenes": count, "median_s": round(statistics.median(seconds), 3),
                      "optimizer_s_per_scene": round(statistics.median(optimizer), 3),
                      "history_digest": digest.hexdigest()[:16]}))


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 5)
