"""The perturbation search space and its feasible set Q.

A perturbation of m vehicles is x in [-1, 1]^(3m): per vehicle (dx, dy, dyaw) divided by the
bounds (2.5 m, 2.5 m, 45 deg), dx and dy in the network frame. Q holds N_Q joint samples, uniform
over the plausible ones: every moved vehicle stays on the drivable area, collides with nothing and
stays in the evaluation range (see FeasibleSet for how they are drawn). Projection onto Q: nearest
member in normalised units (L2).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal, Sequence

import numpy as np

from sumo_scenarios import checks
from sumo_scenarios.errors import InputError

from ..scene import Agent, Scene
from ..scene.feasibility import FeasibilityChecker, box_object, collide_boxes


@dataclass(frozen=True)
class SpaceConfig:
    dxy_m: float = 2.5
    dyaw_deg: float = 45.0
    n_q: int = 1000
    #: at most this many draws (x n_q) while filling Q
    max_draw_factor: int = 20
    #: what a moved vehicle must respect: "paper" (on the drivable area, no collision, in range) or
    #: "traffic" (also in a lane of its own direction, heading within traffic_heading_deg of it)
    plausibility: Literal["paper", "traffic"] = "paper"
    traffic_heading_deg: float = 30.0

    def __post_init__(self) -> None:
        checks.number(self.dxy_m, "space.dxy_m", 0.0, MAX_DXY_M, lo_open=True)
        checks.number(self.dyaw_deg, "space.dyaw_deg", 0.0, 180.0, lo_open=True)
        checks.number(self.n_q, "space.n_q", 1, 1_000_000)
        checks.number(self.max_draw_factor, "space.max_draw_factor", 1, 10_000)
        if self.plausibility not in ("paper", "traffic"):
            raise InputError(f"space.plausibility must be paper or traffic, got {self.plausibility!r}")
        checks.number(self.traffic_heading_deg, "space.traffic_heading_deg", 0.0, 90.0, lo_open=True)

    def scale_per_vehicle(self) -> np.ndarray:
        """(3,) the bounds of one vehicle's move: dx_m, dy_m, dyaw_rad (x = 1 in normalised units)."""
        return np.array([self.dxy_m, self.dxy_m, math.radians(self.dyaw_deg)])


#: a move larger than this (m) is no longer a nudge within the lane's neighbourhood
MAX_DXY_M = 20.0


def nearest_index(points: np.ndarray, x: np.ndarray) -> int:
    """Row of ``points`` (K, D) nearest to ``x`` (D,) in L2 (the first of ties)."""
    return int(np.argmin(np.sum((points - np.asarray(x)[None]) ** 2, axis=1)))


class EmptyFeasibleSet(InputError):
    """No sampled perturbation is plausible (e.g. vehicles boxed in): the scene cannot be perturbed."""


class SearchSpace:
    def __init__(self, scene: Scene, vehicle_ids: Sequence[str], cfg: SpaceConfig = SpaceConfig()):
        self.scene = scene
        self.vehicle_ids = tuple(vehicle_ids)
        self.cfg = cfg
        self.scale = np.tile(cfg.scale_per_vehicle(), len(self.vehicle_ids))

    @property
    def dim(self) -> int:
        return 3 * len(self.vehicle_ids)

    def denormalise(self, x: np.ndarray) -> np.ndarray:
        """(3m,) normalised → (m, 3) dx_m, dy_m, dyaw_rad."""
        return (np.asarray(x) * self.scale).reshape(-1, 3)

    def moved_agents(self, x: np.ndarray) -> dict[str, Agent]:
        deltas = self.denormalise(x)
        return {vid: self.scene.agent(vid).moved(*d) for vid, d in zip(self.vehicle_ids, deltas)}


@dataclass
class _Pool:
    """One vehicle's moves that pass its own constraints: normalised (K, 3), the moved vehicle's
    fcl boxes and centres (K, 2), the draws used, and the radius of the circle around its footprint."""

    x: np.ndarray
    objects: list
    xy: np.ndarray
    drawn: int
    radius_m: float


class FeasibleSet:
    """Q: plausible joint perturbations (K, 3m) in normalised units; row 0 is always 'no move'.

    Sampled in two steps, with the same distribution as drawing joint perturbations uniformly and
    rejecting the implausible ones, but far fewer draws: each vehicle's own constraints (on the
    drivable area, in range, clear of everything that does not move) do not depend on the other
    moved vehicles, so each vehicle first gets a pool of uniform moves that pass them; joint
    samples then combine one move from each pool at random and are kept only if the moved
    vehicles stay clear of each other. Joint rejection sampling needs about 1 / (p_1 ... p_m)
    draws per member; in a dense lane (p_i of a few percent each) it filled only a few dozen of
    the 1000 members in 20,000 draws.
    """

    def __init__(self, space: SearchSpace, rng: np.random.Generator):
        self.space = space
        checker = FeasibilityChecker(space.scene, space.vehicle_ids, space.cfg.plausibility,
                                     space.cfg.traffic_heading_deg)
        budget = space.cfg.n_q * space.cfg.max_draw_factor
        pools = [self._vehicle_pool(checker, vid, rng, budget) for vid in space.vehicle_ids]
        self.drawn = sum(p.drawn for p in pools)
        empty = [vid for vid, p in zip(space.vehicle_ids, pools) if not len(p.x)]
        if empty:
            raise EmptyFeasibleSet(
                f"scene {space.scene.scene_id}: no plausible move for vehicle {empty[0]} in {budget} draws; "
                "the scene cannot be perturbed")
        kept = [np.zeros(space.dim)]
        drawn = 0
        while len(kept) < space.cfg.n_q + 1 and drawn < budget:
            batch = min(256, budget - drawn)
            picks = np.stack([rng.integers(0, len(p.x), size=batch) for p in pools], axis=1)  # (batch, m)
            drawn += batch
            for row in picks[self._clear_pairs(pools, picks)]:
                kept.append(np.concatenate([p.x[k] for p, k in zip(pools, row)]))
                if len(kept) >= space.cfg.n_q + 1:
                    break
        self.drawn += drawn
        self.members = np.array(kept)
        if len(self.members) < 2:
            raise EmptyFeasibleSet(
                f"scene {space.scene.scene_id}: no plausible joint move for vehicles {', '.join(space.vehicle_ids)} "
                f"in {drawn} draws (each can move alone, not together); the scene cannot be perturbed")

    @staticmethod
    def _clear_pairs(pools: list["_Pool"], picks: np.ndarray) -> np.ndarray:
        """(batch,) bool: the picked moves (batch, m) keep every pair of moved vehicles apart.
        Pairs whose bounding circles are apart are clear without asking fcl."""
        ok = np.ones(len(picks), dtype=bool)
        for i in range(len(pools)):
            for j in range(i + 1, len(pools)):
                gap = np.linalg.norm(pools[i].xy[picks[:, i]] - pools[j].xy[picks[:, j]], axis=1)
                near = np.flatnonzero(ok & (gap < pools[i].radius_m + pools[j].radius_m))
                for r in near:
                    ok[r] = not collide_boxes(pools[i].objects[picks[r, i]], pools[j].objects[picks[r, j]])
        return ok

    def _vehicle_pool(self, checker: FeasibilityChecker, vehicle_id: str, rng: np.random.Generator,
                      budget: int) -> "_Pool":
        """Up to N_Q uniform moves of one vehicle that pass its own constraints."""
        base = self.space.scene.agent(vehicle_id)
        scale = self.space.scale[:3]
        xs: list[np.ndarray] = []
        objects: list = []
        xy: list[tuple[float, float]] = []
        drawn = 0
        while len(xs) < self.space.cfg.n_q and drawn < budget:
            batch = min(512, budget - drawn)
            draws = rng.uniform(-1.0, 1.0, size=(batch, 3))
            drawn += batch
            moved = [base.moved(*(x * scale)) for x in draws]
            ok = checker.on_road(moved) & checker.in_range(moved)
            for x, a in zip(draws[ok], (a for a, k in zip(moved, ok) if k)):
                box = box_object(a)
                if not checker.touches_fixed(box):
                    xs.append(x)
                    objects.append(box)
                    xy.append((a.x_m, a.y_m))
                    if len(xs) >= self.space.cfg.n_q:
                        break
        return _Pool(np.array(xs).reshape(-1, 3), objects, np.array(xy).reshape(-1, 2), drawn,
                     0.5 * math.hypot(base.length_m, base.width_m))

    def __len__(self) -> int:
        return len(self.members)

    def project(self, x: np.ndarray) -> np.ndarray:
        """The member of Q nearest to ``x`` in normalised units."""
        return self.members[nearest_index(self.members, x)]

    def sample(self, rng: np.random.Generator) -> np.ndarray:
        return self.members[int(rng.integers(1, len(self.members)))]
