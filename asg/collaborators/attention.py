"""ACS-A: combinations drawn by the weakness of their members in the attention model's eyes."""
from __future__ import annotations

from typing import Sequence

import numpy as np

from ..scene import Scene
from .base import ACS_STRATEGIES, AttentionOf, CollaboratorSearch
from .sampling import all_combinations, attention_combinations


@ACS_STRATEGIES.register("attention")
class AttentionSearch(CollaboratorSearch):
    """``samples`` combinations drawn without replacement from softmax(weakness / tau), the
    weakness of a combination the sum of 1 / s_j over its members (asg.collaborators.sampling)."""

    needs_attention = True

    def propose(self, scene: Scene, candidates: Sequence[str], size: int, rng: np.random.Generator,
                attention_of: AttentionOf | None) -> tuple[list[tuple[str, ...]], dict[str, float]]:
        weights = attention_of(scene.with_collaborators(list(candidates)))
        combos, p = attention_combinations(weights, candidates, size, self.samples, self.tau, rng)
        probs = {"+".join(c): float(v) for c, v in zip(all_combinations(candidates, size), p) if v > 1e-4}
        return combos, probs
