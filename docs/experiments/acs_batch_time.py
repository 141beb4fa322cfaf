"""The scene as given scored apart from the collaborator search, or in one batch with its
combinations (``Generator.normal_and_acs``): ms a scene of each way, alternating in one process on
two threads (``asg bench generate``'s setting: candidates on two threads, one torch thread each),
and whether both ways give the same scores, detections and collaborators.
usage: .venv/bin/python docs/experiments/acs_batch_time.py SCENES ROUNDS > OUT.json
"""
import itertools
import json
import statistics
import subprocess
import sys
import time

import asg  # noqa: F401  (first: it sets how OpenMP's threads wait, read when torch loads)
import numpy as np
from asg.datasets import scenes_of
from asg.executors import apply_threads
from asg.executors.base import blas_on_one_thread
from asg.generator.config import load_generate_config
from asg.generator.pipeline import Generator
from asg.perception import build_detector


def same(a, b) -> bool:
    """Two scored scenes alike: loss, AP, every detection array, the collaborators."""
    return (a.loss, a.ap, a.scene.collaborators) == (b.loss, b.ap, b.scene.collaborators) and all(
        np.array_equal(x, y) for x, y in zip(a.detections, b.detections, strict=True))


def main(count: int, rounds: int) -> None:
    apply_threads(2)
    cfg = load_generate_config(fusion="attfuse", search="bo", acs="attention", budget=50)
    det = build_detector("attfuse")
    gen = Generator(cfg, det, det, candidate_threads=2)
    scenes = [gen.normal_collaborators(s, np.random.default_rng(0), [])
              for s in itertools.islice(scenes_of("normal"), 0, 10 * count, 10)]

    def apart(scene):
        return gen.evaluate_scene(scene), gen.collaborator_search(scene, np.random.default_rng(1), [])

    def in_batch(scene):
        return gen.normal_and_acs(scene, np.random.default_rng(1), [])

    ways = {"apart": apart, "in_batch": in_batch}
    ms = {name: [] for name in ways}
    agree = True
    with blas_on_one_thread():
        in_batch(scenes[0])  # warm-up
        for _ in range(rounds):
            for scene in scenes:
                got = {}
                for name, way in ways.items():
                    t = time.perf_counter()
                    got[name] = way(scene)
                    ms[name].append((time.perf_counter() - t) * 1e3)
                (n1, acs1), (n2, acs2) = got["apart"], got["in_batch"]
                agree &= same(n1, n2) and same(acs1.best, acs2.best) and acs1.probabilities == acs2.probabilities
    ratios = [b / a for a, b in zip(ms["apart"], ms["in_batch"])]
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    print(json.dumps({"commit": commit, "scenes": count, "rounds": rounds,
                      "apart_ms_median": round(statistics.median(ms["apart"]), 1),
                      "in_batch_ms_median": round(statistics.median(ms["in_batch"]), 1),
                      "in_batch_over_apart_median": round(statistics.median(ratios), 3),
                      "same_results": bool(agree)}))


if __name__ == "__main__":
    main(int(sys.argv[1]), int(sys.argv[2]))
