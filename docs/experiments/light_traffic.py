"""Experiment (outside the package): the `normal` set with lighter traffic.

usage: .venv/bin/python docs/experiments/light_traffic.py PER_LANE_KM
writes runs/experiments/light{PER_LANE_KM}/data/normal (the set) and .../scenes-30 (the benchmark's
pick of it), and prints the vehicles within the evaluation range per frame. Then, for example:
ASG_DATA=runs/experiments/light7/data asg evaluate --fusion attfuse --set normal --json
asg generate --scenes runs/experiments/light7/scenes-30 --fusion attfuse --search bo --acs attention
    --count 30 --budget 50 --seed 1 --out runs/experiments/light7/attention-bo
"""
import functools, os, statistics, sys
from pathlib import Path

per_km = float(sys.argv[1])
root = Path("runs/experiments") / f"light{per_km:g}"
os.environ["ASG_DATA"] = str(root / "data")

import sumo_scenarios.simulate as sim
from sumo_scenarios.routes import TrafficParams
sim.TrafficParams = functools.partial(TrafficParams, normal_per_lane_km=per_km)

from asg.benchmarks.paper import pick_scenes
from asg.datasets import build_dataset, iter_frames
from asg.scene.feasibility import in_eval_range

out = build_dataset("normal")
counts = [int(in_eval_range(s.ego, [v for v in s.vehicles if v.agent_id != s.ego_id]).sum()) for s in iter_frames(out)]
print("frames", len(counts), "vehicles in range mean %.1f median %g min %d max %d"
      % (statistics.mean(counts), statistics.median(counts), min(counts), max(counts)))
pick_scenes(root / "scenes-30", 30)
