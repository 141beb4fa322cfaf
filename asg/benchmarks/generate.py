"""``asg bench generate``: per-scene wall time of AttFuse + ACS-A + a search (BO, 50 evaluations),
the evaluation rate, and the search's own overhead per suggestion (ask + tell)."""
from __future__ import annotations

import itertools
import statistics
import time

import numpy as np

from ..perception import build_detector
from ..datasets import scenes_of
from ..generator.config import GenerateConfig, load_generate_config
from ..generator.pipeline import Generator
from .defaults import GENERATE_SCENES


def bench_generate(scenes: int = GENERATE_SCENES, budget: int = GenerateConfig.budget, seed: int = 1,
                   search: str = GenerateConfig.search) -> dict:
    """One process on two threads: the scenes' normal and ACS frames detected on two torch
    threads, the search's batches of candidates on two threads of one (asg.generator.candidates)."""
    import torch

    torch.set_num_threads(2)
    cfg = load_generate_config(fusion="attfuse", search=search, acs="attention", budget=budget)
    det = build_detector("attfuse")
    gen = Generator(cfg, det, det, candidate_threads=torch.get_num_threads())
    seconds, evals, overhead = [], [], []
    for scene in itertools.islice(scenes_of("normal"), scenes):
        t = time.perf_counter()
        r = gen.attack(scene, seed)
        seconds.append(time.perf_counter() - t)
        evals.append(r.evaluations)
        overhead += r.bo_overhead_s
    return {
        "scenes": len(seconds), "budget": budget, "search": search,
        "seconds_per_scene_median": round(statistics.median(seconds), 2),
        "evaluations_per_second": round(sum(evals) / sum(seconds), 2),
        "bo_overhead_s_median": round(float(np.median(overhead)), 4) if overhead else None,
        "scenes_per_hour": round(3600 * len(seconds) / sum(seconds), 1),
        "goal_seconds_per_scene": 5.0, "goal_bo_overhead_s": 0.1,
    }
