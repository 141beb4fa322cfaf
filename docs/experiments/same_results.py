"""What a change must leave as it was, as digests: the feasible set Q (12 normal scenes x 4 spaces:
the paper's level, the traffic level, poses + insert, 15-degree turns) and whole attacks (AttFuse,
BO budget 20, 6 scenes under ACS-A and ACS-R: every stage's clouds and detections, the ACS
probabilities, the search history and AP). docs/experiments/same_results_ab.sh runs it on two trees.
usage: PYTHONPATH=TREE .venv/bin/python docs/experiments/same_results.py OUT.json
"""
import hashlib
import itertools
import json
import sys

import numpy as np

from asg.datasets import scenes_of
from asg.executors import apply_threads
from asg.generator.config import load_generate_config
from asg.generator.pipeline import Generator
from asg.perception import build_detector
from asg.search.space import EmptyFeasibleSet, FeasibleSet, SearchSpace, SpaceConfig

SPACES = {"paper": SpaceConfig(), "traffic": SpaceConfig(plausibility="traffic"),
          "insert": SpaceConfig(kinds=("poses", "insert")), "turn-steps": SpaceConfig(dyaw_step_deg=15.0)}


def digest(*arrays) -> str:
    h = hashlib.sha256()
    for a in arrays:
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()[:16]


def feasible_sets() -> dict[str, str]:
    gen = Generator(load_generate_config(fusion="attfuse", search="bo", acs="off", budget=50), None, None)
    out = {}
    for i, scene in enumerate(itertools.islice(scenes_of("normal"), 0, 120, 10)):
        scene = gen.normal_collaborators(scene, np.random.default_rng(i), [])
        movers = gen.pick_perturbed(scene, [])
        for name, cfg in SPACES.items():
            try:
                members = FeasibleSet(SearchSpace(scene, movers, cfg), np.random.default_rng(i + 100)).members
            except EmptyFeasibleSet:
                members = np.zeros(0)
            out[f"q {scene.scene_id} {name}"] = digest(members)
    return out


def attacks() -> dict[str, str]:
    detector = build_detector("attfuse")
    out = {}
    for acs in ("attention", "random"):
        gen = Generator(load_generate_config(fusion="attfuse", search="bo", acs=acs, budget=20), detector, detector)
        for scene in itertools.islice(scenes_of("normal"), 0, 60, 10):
            r = gen.attack(scene, 1)
            clouds = [r.frames[k].clouds[a] for k in sorted(r.frames, key=str) for a in r.frames[k].sensing_ids]
            boxes = [a for k in sorted(r.detections, key=str) for a in r.detections[k]]
            record = json.dumps([r.ap_normal, r.ap_after_acs, r.ap_final, r.after_acs.collaborators,
                                 r.acs_probabilities, [[*map(float, e.x), e.loss] for e in r.history]], sort_keys=True)
            out[f"attack {scene.scene_id} acs-{acs}"] = digest(*clouds, *boxes, np.frombuffer(record.encode(), np.uint8))
    return out


if __name__ == "__main__":
    apply_threads(1)
    with open(sys.argv[1], "w") as f:
        json.dump({**feasible_sets(), **attacks()}, f, indent=0)
