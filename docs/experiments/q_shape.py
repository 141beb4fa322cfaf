"""How the drivable-area constraint shapes Q on the benchmark scenes (after ACS, perturbed ids from summary).

Over the scenes: Q's size and draws, and |dyaw| (deg) and |dxy| (m) of Q's members, with and
without the on-road test (the paper's Q: no overlap, in range only).
usage: .venv/bin/python docs/experiments/q_shape.py RUN_DIR   (an ACS-A + BO run folder, e.g.
runs/bench/attfuse/attention-bo after `asg bench paper`)
"""
import json, sys, math
from pathlib import Path
import numpy as np
from asg.scene.scene import load_scene
from asg.search.space import SearchSpace, FeasibleSet, SpaceConfig
from asg.scene import feasibility

root = Path(sys.argv[1])
summary = json.loads((root / "summary.json").read_text())
rows = {"road": [], "paper": []}
chosen = []
for s in summary["scenes"]:
    if not s["perturbed"]:
        continue
    scene = load_scene(root / "scenes" / s["scene_id"] / "after_acs.yaml")
    for mode in ("road", "paper"):
        orig = feasibility.FeasibilityChecker.on_road
        if mode == "paper":
            feasibility.FeasibilityChecker.on_road = lambda self, agents: np.ones(len(agents), dtype=bool)
        try:
            space = SearchSpace(scene, s["perturbed"], SpaceConfig())
            q = FeasibleSet(space, np.random.default_rng(0))
        finally:
            feasibility.FeasibilityChecker.on_road = orig
        m = q.members[1:].reshape(len(q.members) - 1, -1, 3)
        rows[mode].append((len(q.members) - 1, q.drawn, np.abs(m[..., 2]).mean() * 45, (np.abs(m[..., 2]) > 0.5).mean(),
                           np.hypot(m[..., 0], m[..., 1]).mean() * 2.5))
    if s["delta"]:
        d = np.array(s["delta"])
        chosen.append((np.degrees(np.abs(d[:, 2])).mean(), np.hypot(d[:, 0], d[:, 1]).mean()))
for mode, r in rows.items():
    r = np.array(r)
    print(f"{mode}: scenes {len(r)}, |Q| median {np.median(r[:,0]):.0f}, draws median {np.median(r[:,1]):.0f}, "
          f"mean |dyaw| {r[:,2].mean():.1f} deg, share |dyaw|>22.5 deg {r[:,3].mean():.2f}, mean |dxy| {r[:,4].mean():.2f} m")
c = np.array(chosen)
print(f"chosen (best) moves: {len(c)} scenes, mean |dyaw| {c[:,0].mean():.1f} deg, mean |dxy| {c[:,1].mean():.2f} m")
