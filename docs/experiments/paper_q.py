"""Ablation (not shipped): ACS-A + BO on the benchmark scenes with the paper's Q (no drivable-area test:
no overlap and in range only). The on-road test is switched off everywhere, including the final,
independent re-check (asg/scene/recheck.py).
usage: .venv/bin/python docs/experiments/paper_q.py SCENE_DIR OUT [acs search]
(SCENE_DIR: the benchmark's scene pick, e.g. runs/bench/attfuse/scenes-30 after `asg bench paper`)
"""
import sys
from pathlib import Path
import numpy as np
import shapely
from asg.scene import feasibility, recheck
from asg.benchmarks.paper import run_config

feasibility.FeasibilityChecker.on_road = lambda self, agents: np.ones(len(agents), dtype=bool)
recheck._drivable = lambda scene: shapely.box(-1e7, -1e7, 1e7, 1e7)  # everywhere counts as road
acs, search = (sys.argv[3], sys.argv[4]) if len(sys.argv) > 4 else ("attention", "bo")
run_config(Path(sys.argv[2]), Path(sys.argv[1]), acs, search, 30, 50, "attfuse", 1)
