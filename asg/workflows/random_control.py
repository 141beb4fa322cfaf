"""The random control of hardening: a scene with one plausible perturbation drawn at random from
the feasible set the attack would search (the same movers, spaces and plausibility level), so that a
round trained on such scenes costs what an adversarial round costs, without the search."""
from __future__ import annotations

import numpy as np

from sumo_scenarios.errors import InputError

from ..scene import Scene

#: the seed of the attacks and of the noise (as the challenging sets')
ATTACK_SEED = 1


def random_draw(scene: Scene, gen_cfg, seed: int) -> Scene:
    """``scene`` with one plausible perturbation drawn uniformly from the members of the feasible
    set the search would use (same movers by the occlusion heuristic, same spaces and plausibility
    level), its collaborators as they are; the scene itself when nothing can move."""
    from ..generator.pipeline import Generator
    from ..search import EmptyFeasibleSet, FeasibleSet, SearchSpace

    rng = np.random.default_rng([seed, *(ord(ch) for ch in scene.scene_id[-16:])])
    gen = Generator(gen_cfg, target=None)
    perturbed = gen.pick_perturbed(scene, []) if gen_cfg.space.needs_movers else []
    try:
        space = SearchSpace(scene, perturbed, gen_cfg.space)
        if space.dim == 0:
            return scene
        members = FeasibleSet(space, rng).members
    except (EmptyFeasibleSet, InputError):
        return scene
    if len(members) < 2:
        return scene
    return space.apply(members[1 + int(rng.integers(len(members) - 1))])  # members[0] is the scene itself
