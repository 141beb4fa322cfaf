"""ACS-R: combinations drawn uniformly (the paper's random baseline)."""
from __future__ import annotations

from typing import Sequence

import numpy as np

from ..scene import Scene
from .base import ACS_STRATEGIES, AttentionOf, CollaboratorSearch
from .sampling import random_combinations


@ACS_STRATEGIES.register("random")
class RandomSearch(CollaboratorSearch):
    """``samples`` combinations drawn uniformly without replacement."""

    def propose(self, scene: Scene, candidates: Sequence[str], size: int, rng: np.random.Generator,
                attention_of: AttentionOf | None) -> tuple[list[tuple[str, ...]], dict[str, float]]:
        return random_combinations(candidates, size, self.samples, rng), {}
