"""How long drawing the feasible set Q takes at each plausibility level: FeasibleSet on SCENES scenes
of the `normal` set (every 6th, two collaborators, up to 3 movers), the paper's space settings,
seed 7; median seconds a scene over ROUNDS rounds, and a digest of every set drawn (two commits
that draw the same sets print the same digest). Run it with PYTHONPATH set to a checkout of the
commit measured, alternating commits.
usage: PYTHONPATH=TREE .venv/bin/python docs/experiments/feasible_set_time.py [SCENES] [ROUNDS]
"""
import dataclasses
import hashlib
import itertools
import json
import statistics
import sys
import time

import numpy as np

from asg.datasets import scenes_of
from asg.generator.config import load_generate_config
from asg.scene.feasibility import in_eval_range
from asg.scene.neighbours import with_nearest_collaborators
from asg.search.space import FeasibleSet, SearchSpace


def spaces(count: int, plausibility: str) -> list[SearchSpace]:
    space_cfg = dataclasses.replace(load_generate_config(fusion="attfuse", budget=50).space, plausibility=plausibility)
    out = []
    for scene in itertools.islice(scenes_of("normal"), 0, 6 * count, 6):
        scene = with_nearest_collaborators(scene, 2)
        others = [a for a in scene.agents if a.is_vehicle and a.agent_id not in scene.sensing_ids]
        movers = [a.agent_id for a, ok in zip(others, in_eval_range(scene.ego, others)) if ok][:3]
        out.append(SearchSpace(scene, movers, space_cfg))
    return out


def main(count: int, rounds: int) -> None:
    result = {}
    for level in ("paper", "traffic"):
        built = spaces(count, level)
        times, digest = [], hashlib.sha256()
        for r in range(rounds):
            for space in built:
                t = time.perf_counter()
                members = FeasibleSet(space, np.random.default_rng(7)).members
                times.append(time.perf_counter() - t)
                if r == 0:
                    digest.update(members.tobytes())
        result[level] = {"median_s": round(statistics.median(times), 3), "sets_digest": digest.hexdigest()[:16]}
    print(json.dumps({"scenes": count, "rounds": rounds} | result))


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 10, int(sys.argv[2]) if len(sys.argv) > 2 else 2)
