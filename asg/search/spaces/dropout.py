"""``dropout``: a collaborator's message lost (one discrete dimension per collaborator: -1 arrives,
+1 lost), at most ``max_lost`` of them in one scene.

Default 1: 3GPP TS 22.186 asks cooperative-awareness messages for 90 % reliability or more, so losing
one message of a frame is a plausible event and losing every one of several a rare one.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sumo_scenarios import checks

from .base import SPACES, PerturbationSpace, collaborators


@dataclass(frozen=True)
class DropoutConfig:
    max_lost: int = 1

    def __post_init__(self) -> None:
        checks.number(self.max_lost, "space.dropout.max_lost", 1, 16)


@SPACES.register("dropout")
class DropoutSpace(PerturbationSpace):
    @property
    def width(self) -> int:
        return len(collaborators(self.ctx))

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """Uniform over the number lost (0..max_lost), then over which collaborators."""
        out = -np.ones((n, self.width))
        most = min(self.cfg.dropout.max_lost, self.width)
        for row, lost in enumerate(rng.integers(0, most + 1, size=n)):
            out[row, rng.choice(self.width, size=int(lost), replace=False)] = 1.0
        return out

    def identity(self) -> np.ndarray:
        return -np.ones(self.width)

    def link_fields(self, x: np.ndarray) -> dict[str, dict]:
        return {cid: {"dropped": bool(v > 0)} for cid, v in zip(collaborators(self.ctx), np.asarray(x))}

    def link_columns(self) -> list[str]:
        return [f"{c}_lost" for c in collaborators(self.ctx)]

    def link_readable(self, x: np.ndarray) -> list[float]:
        return [float(v > 0) for v in np.asarray(x)]

    def bounds(self) -> dict:
        return {"max_lost": self.cfg.dropout.max_lost}
