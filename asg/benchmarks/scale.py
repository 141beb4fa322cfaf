"""``asg bench scale``: scenes per hour of the generator benchmark (AttFuse + ACS-A + BO) run four
ways in one run, and the speedups between them:

- ``local_1``: one worker, one thread (the other core left idle: its search's candidates are
  not scored beside it);
- ``local_1_all``: one worker using every core's thread (one process, as ``asg generate`` ran
  before executors);
- ``local_2``: two worker processes, one thread each;
- ``ray_2``: two Ray actors, one thread each (a local Ray instance, started before the clock).

Every way generates the same scenes into its own run folder under OUT (started over each time)
and, but for ``local_1_all`` (more threads change torch's sums in the last bits), ends with the same
summary numbers: the benchmark checks it. ``scenes_per_hour`` counts the whole wall time, the
workers' start (spawning, imports, loading the models) included; ``steady_scenes_per_hour`` leaves
that start out (until the first scene began), which is what a long batch sees.
"""
from __future__ import annotations

import json
import os
import time
from pathlib import Path

from ..executors import build_executor
from ..generator.run import SceneSource, open_run
from ..generator.config import GenerateConfig, load_generate_config
from ..generator.stages import Stage
from .defaults import SCALE_SCENES
from .paper import pick_scenes

#: (name, executor, workers, threads per worker)
WAYS = (("local_1", "local", 1, 1), ("local_1_all", "local", 1, None), ("local_2", "local", 2, 1),
        ("ray_2", "ray", 2, 1))


def _numbers(out: Path) -> list:
    """The scenes' AP and loss, without timings."""
    summary = json.loads((out / "summary.json").read_text())
    return [(e["scene_id"], e[Stage.FINAL.ap_key], e["loss_final"]) for e in summary["scenes"]]


def bench_scale(out: Path, scenes: int = SCALE_SCENES, budget: int = GenerateConfig.budget, seed: int = 1, ways: tuple = WAYS) -> dict:
    cfg = load_generate_config(fusion="attfuse", search="bo", acs="attention", budget=budget)
    scene_dir = pick_scenes(out / f"scenes-{scenes}", scenes)
    source = SceneSource(scenes=scene_dir)
    result: dict = {"scenes": scenes, "budget": budget, "cpu_count": os.cpu_count()}
    numbers = {}
    for name, executor_name, workers, threads in ways:
        run_dir = out / name
        run_folder = open_run(cfg, run_dir, source=source, count=scenes, seed=seed, force=True)
        with build_executor(executor_name, workers, threads or (os.cpu_count() or 1),
                            idle_cores=name != "local_1") as executor:
            if executor_name == "ray":
                executor.connect()  # Ray's own start-up is not the generator's cost
            first: list = []
            t0 = time.perf_counter()
            run = run_folder.run(
                executor=executor, on_scene=lambda n, total, sid: first or first.append((time.perf_counter() - t0, sid)))
            wall = time.perf_counter() - t0
        seconds = {e["scene_id"]: e["seconds"] for e in run.summary["scenes"]}
        startup = max(0.0, first[0][0] - seconds[first[0][1]])  # until the first scene started
        result[name] = {"wall_s": round(wall, 1), "startup_s": round(startup, 1),
                        "scenes_per_hour": round(3600 * scenes / wall, 1),
                        "steady_scenes_per_hour": round(3600 * scenes / (wall - startup), 1),
                        "seconds_per_scene_mean": round(sum(seconds.values()) / len(seconds), 2)}
        numbers[name] = _numbers(run_dir)
    for key in ("scenes_per_hour", "steady_scenes_per_hour"):
        rate = {k: result[k][key] for k, *_ in ways}
        prefix = "speedup" if key == "scenes_per_hour" else "steady_speedup"
        for a, b in (("local_2", "local_1"), ("local_2", "local_1_all"), ("ray_2", "local_1"),
                     ("ray_2", "local_1_all"), ("local_1_all", "local_1")):
            if a in rate and b in rate:
                result[f"{prefix}_{a}_over_{b}"] = round(rate[a] / rate[b], 3)
    one_thread = [numbers[k] for k in numbers if k != "local_1_all"]
    result["same_numbers_one_thread_ways"] = all(n == one_thread[0] for n in one_thread)
    result["goal_speedup_2_workers_over_local_1"] = 1.8
    result["goal_speedup_2_workers_over_local_1_all"] = 1.25
    return result
