"""Do the two plausibility checks agree? Every FIRST members of the feasible set Q (built with the
fcl checker) of every STEP-th `normal` scene, re-checked by the independent shapely path
(asg/scene/recheck.py); prints how many it refused.
usage: .venv/bin/python docs/experiments/recheck_agreement.py [STEP] [FIRST]     (default 7 300)
"""
import itertools
import sys

import numpy as np

from asg.datasets import scenes_of
from asg.generator.pipeline import GenerateConfig, Generator
from asg.scene.recheck import recheck
from asg.search import EmptyFeasibleSet, FeasibleSet, SearchSpace, SpaceConfig


class _NoDetector:
    """Picking the perturbed vehicles needs no detector."""


def main(step: int, first: int) -> None:
    gen = Generator(GenerateConfig(fusion="none", search="rs"), _NoDetector(), None)
    checked = refused = scenes = 0
    for scene in itertools.islice(scenes_of("normal"), 0, None, step):
        ids = gen.pick_perturbed(scene, [])
        if not ids:
            continue
        space = SearchSpace(scene, ids, SpaceConfig())
        try:
            q = FeasibleSet(space, np.random.default_rng(0))
        except EmptyFeasibleSet:
            continue
        scenes += 1
        for x in q.members[:first]:
            moved = space.moved_agents(x)
            result = recheck(scene, scene.with_agents([moved.get(a.agent_id, a) for a in scene.agents]))
            checked += 1
            if not result.ok:
                refused += 1
                print(scene.scene_id, result.to_dict())
    print(f"{scenes} scenes, {checked} members of Q re-checked, {refused} refused")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 7, int(sys.argv[2]) if len(sys.argv) > 2 else 300)
