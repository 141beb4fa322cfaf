"""The collaborator search's strategy: which collaborator combinations ACS evaluates.

A strategy is registered by name (``@ACS_STRATEGIES.register(NAME)``) and chosen with ``--acs NAME`` /
generate.yaml's ``acs``; ``off`` (no search: the scene's own collaborators) needs none. The
generator evaluates every proposed combination and keeps the one with the lowest loss.
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Callable, Mapping, Sequence

import numpy as np

from ..registry import Registry
from ..scene import Scene

#: the attention weight s_j of each candidate j, from a frame where every candidate collaborates
AttentionOf = Callable[[Scene], Mapping[str, float]]


class CollaboratorSearch(ABC):
    """Proposes ``samples`` combinations of ``size`` collaborators among the candidates."""

    registry_name: str = ""
    #: does ``propose`` read attention weights (then the generator needs an attention model)?
    needs_attention: bool = False

    def __init__(self, samples: int, tau: float):
        self.samples = samples
        self.tau = tau

    @abstractmethod
    def propose(self, scene: Scene, candidates: Sequence[str], size: int, rng: np.random.Generator,
                attention_of: AttentionOf | None) -> tuple[list[tuple[str, ...]], dict[str, float]]:
        """The combinations to evaluate, and each possible combination's probability ("a+b": p) for
        the record ({} when the strategy has none). ``attention_of``: given when ``needs_attention``."""


#: the collaborator searches (``--acs``), one module of this package each, filled by its import
ACS_STRATEGIES: "Registry[type[CollaboratorSearch]]" = Registry("collaborator search", "--acs")
