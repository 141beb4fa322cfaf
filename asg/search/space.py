"""The perturbation search space and its feasible set Q.

A perturbation of m vehicles is x in [-1, 1]^(3m): per vehicle (dx, dy, dyaw) divided by the
bounds (2.5 m, 2.5 m, 45 deg), dx and dy in the network frame. Q holds N_Q joint samples, drawn
uniformly and kept only if every moved vehicle stays on the drivable area, collides with nothing
and stays in the evaluation range. Projection onto Q: nearest member in normalised units (L2).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from sumo_scenarios.errors import InputError

from ..scene import Agent, Scene
from ..scene.feasibility import FeasibilityChecker


@dataclass(frozen=True)
class SpaceConfig:
    dxy_m: float = 2.5
    dyaw_deg: float = 45.0
    n_q: int = 1000
    #: at most this many draws (x n_q) while filling Q
    max_draw_factor: int = 20


class EmptyFeasibleSet(InputError):
    """No sampled perturbation is plausible (e.g. vehicles boxed in): the scene cannot be perturbed."""


class SearchSpace:
    def __init__(self, scene: Scene, vehicle_ids: Sequence[str], cfg: SpaceConfig = SpaceConfig()):
        self.scene = scene
        self.vehicle_ids = tuple(vehicle_ids)
        self.cfg = cfg
        self.scale = np.tile([cfg.dxy_m, cfg.dxy_m, math.radians(cfg.dyaw_deg)], len(self.vehicle_ids))

    @property
    def dim(self) -> int:
        return 3 * len(self.vehicle_ids)

    def denormalise(self, x: np.ndarray) -> np.ndarray:
        """(3m,) normalised → (m, 3) dx_m, dy_m, dyaw_rad."""
        return (np.asarray(x) * self.scale).reshape(-1, 3)

    def moved_agents(self, x: np.ndarray) -> dict[str, Agent]:
        deltas = self.denormalise(x)
        return {vid: self.scene.agent(vid).moved(*d) for vid, d in zip(self.vehicle_ids, deltas)}


class FeasibleSet:
    """Q: plausible joint perturbations (K, 3m) in normalised units; row 0 is always 'no move'."""

    def __init__(self, space: SearchSpace, rng: np.random.Generator):
        self.space = space
        checker = FeasibilityChecker(space.scene, space.vehicle_ids)
        kept = [np.zeros(space.dim)]
        drawn = 0
        batch = 256
        while len(kept) < space.cfg.n_q + 1 and drawn < space.cfg.n_q * space.cfg.max_draw_factor:
            xs = rng.uniform(-1.0, 1.0, size=(batch, space.dim))
            drawn += batch
            ok = self._cheap_filter(checker, xs)
            for x in xs[ok]:
                if checker.collides(list(space.moved_agents(x).values())) == 0:
                    kept.append(x)
                    if len(kept) >= space.cfg.n_q + 1:
                        break
        self.members = np.array(kept)
        self.drawn = drawn
        if len(self.members) < 2:
            raise EmptyFeasibleSet(
                f"scene {space.scene.scene_id}: no plausible move for vehicles {', '.join(space.vehicle_ids)} "
                f"in {drawn} draws; the scene cannot be perturbed")

    def _cheap_filter(self, checker: FeasibilityChecker, xs: np.ndarray) -> np.ndarray:
        """On road and in range for every moved vehicle (vectorised over samples)."""
        agents = [a for x in xs for a in self.space.moved_agents(x).values()]
        m = len(self.space.vehicle_ids)
        ok = (checker.on_road(agents) & checker.in_range(agents)).reshape(len(xs), m)
        return ok.all(axis=1)

    def __len__(self) -> int:
        return len(self.members)

    def project(self, x: np.ndarray) -> np.ndarray:
        """The member of Q nearest to ``x`` in normalised units."""
        d = np.sum((self.members - np.asarray(x)[None]) ** 2, axis=1)
        return self.members[int(np.argmin(d))]

    def sample(self, rng: np.random.Generator) -> np.ndarray:
        return self.members[int(rng.integers(1, len(self.members)))]
