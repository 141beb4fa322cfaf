"""``asg bench detect``: median inference time per frame of each shipped model (3 sensing agents)."""
from __future__ import annotations

import itertools
import statistics
import time

from ..perception import build_detector
from ..datasets import scenes_of
from ..scene.neighbours import with_nearest_collaborators
from ..sensors import load_lidar_spec, simulate_frame


def models() -> list[str]:
    """A row per shipped model with a network of its own: every registered fusion but the
    fine-tuned twins (attfuse-ft runs AttFuse's network, at AttFuse's cost)."""
    from ..perception.fusion import FUSIONS

    return [n for n in FUSIONS.names() if not FUSIONS.entry(n).fine_tuned_from]


def bench_detect(frames: int = 10, repeats: int = 3) -> dict:
    import torch

    torch.set_num_threads(2)
    spec = load_lidar_spec()
    scenes = [with_nearest_collaborators(s, 2) for s in itertools.islice(scenes_of("normal"), frames)]
    coop = [simulate_frame(s, spec) for s in scenes]
    out = {"frames": len(coop), "agents_per_frame": round(statistics.mean(len(f.sensing_ids) for f in coop), 2),
           "threads": torch.get_num_threads()}
    for name in models():
        det = build_detector(name)
        det.detect(coop[0])  # warm-up
        times = []
        for _ in range(repeats):
            for f in coop:
                t = time.perf_counter()
                det.detect(f)
                times.append(time.perf_counter() - t)
        out[f"{name}_ms_median"] = round(statistics.median(times) * 1e3, 1)
    out["goal_attfuse_ms"] = 60.0
    return out
