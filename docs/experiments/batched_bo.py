"""Batched BO against sequential BO on the paper's protocol: AttFuse + ACS-A + BO-50 on the 30
scenes of ``asg bench paper`` (``pick_scenes``), with ``batch`` of configs/search/bo.yaml at 1 (the
paper's) and at each BATCH given, one worker on two cores (a batch's candidates scored side by
side); prints and writes JSON: pooled AP before and after, the drop at 0.7, the run's wall time.
usage: .venv/bin/python docs/experiments/batched_bo.py OUT_DIR [BATCH ...]   (default: 5)
"""
import json
import sys
import time
from pathlib import Path

from asg.benchmarks.paper import pick_scenes
from asg.executors import build_executor
from asg.generator import config as generate_config
from asg.generator import pipeline
from asg.generator.config import load_generate_config
from asg.generator.run import SceneSource, open_run


def run(out: Path, batch: int) -> dict:
    real = generate_config.search_params
    patched = lambda name: real(name) | ({"batch": batch} if name == "bo" else {})  # noqa: E731
    # configs/search/bo.yaml as if it said ``batch: N``: where the generator and run.json read it
    generate_config.search_params = pipeline.search_params = patched
    try:
        cfg = load_generate_config(fusion="attfuse", search="bo", acs="attention", budget=50)
        source = SceneSource(scenes=pick_scenes(out / "scenes-30", 30))
        folder = open_run(cfg, out / f"bo-batch-{batch}", source=source, count=30, seed=1, force=True)
        with build_executor("local", 1, 1) as executor:
            t = time.perf_counter()
            summary = folder.run(executor=executor).summary
            wall_s = time.perf_counter() - t
    finally:
        generate_config.search_params = pipeline.search_params = real
    agg = summary["aggregate"]
    return {"batch": batch, "wall_s": round(wall_s, 1), "seconds_per_scene": round(wall_s / 30, 2),
            "ap_normal": agg["ap_normal"], "ap_final": agg["ap_final"],
            "drop_at_0.7": round(agg["ap_normal"]["0.7"] - agg["ap_final"]["0.7"], 4),
            "search_settings": json.loads((out / f"bo-batch-{batch}" / "run.json").read_text())["search_settings"]}


def main(out: Path, batches: list[int]) -> None:
    rows = [run(out, b) for b in [1] + batches]
    print(json.dumps(rows, indent=1))
    (out / "batched-bo.json").write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main(Path(sys.argv[1]), [int(b) for b in sys.argv[2:]] or [5])
