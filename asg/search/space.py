"""The perturbation search space and its feasible set Q.

The space is the concatenation of the perturbation spaces named in ``space.kinds`` (asg.search.spaces:
``poses`` is the paper's, m = 3 vehicles each moved within +-2.5 m and +-45 deg; ``insert``,
``pose-error``, ``latency``, ``dropout`` go beyond it). A member x is a vector in normalised units,
[-1, 1] per dimension: first every physical slot (a moved or inserted vehicle), then every link
dimension. Q holds N_Q joint samples, uniform over the plausible ones: every moved or inserted
vehicle stays on the drivable area, collides with nothing and stays in the evaluation range (see
FeasibleSet for how they are drawn); link dimensions are drawn uniformly within their bounds.
Projection onto Q: nearest member in normalised units (L2).

The budget does not grow with the dimensions: every space gets ``--budget`` evaluations, so spaces
and searches are compared at the same cost.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property
from typing import Sequence

import numpy as np

from sumo_scenarios import checks
from sumo_scenarios.errors import InputError

from ..scene import Agent, Scene
from ..scene.feasibility import PLAUSIBILITY_LEVELS, FeasibilityChecker, PlausibilityLevel, box_object_at, collide_boxes
from ..scene.link import LinkState
from .spaces import SPACES, DropoutConfig, InsertConfig, LatencyConfig, PoseErrorConfig, Slot, SpaceContext


@dataclass(frozen=True)
class SpaceConfig:
    #: the perturbation spaces searched together (asg.search.spaces): poses, insert, pose-error, latency, dropout
    kinds: tuple[str, ...] = ("poses",)
    #: poses: one vehicle's move bounds
    dxy_m: float = 2.5
    dyaw_deg: float = 45.0
    #: poses: the turns in steps of this many degrees (0: any turn within +-dyaw_deg); the paper's
    #: code turned vehicles in 15 deg steps (configs/protocols/paper.yaml)
    dyaw_step_deg: float = 0.0
    n_q: int = 1000
    #: at most this many draws (x n_q) while filling Q
    max_draw_factor: int = 20
    #: what a moved vehicle must respect: "paper" (on the drivable area, no collision, in range) or
    #: "traffic" (also in a lane of its own direction, heading within traffic_heading_deg of it)
    plausibility: PlausibilityLevel = "paper"
    traffic_heading_deg: float = 30.0
    insert: InsertConfig = field(default_factory=InsertConfig)
    pose_error: PoseErrorConfig = field(default_factory=PoseErrorConfig)
    latency: LatencyConfig = field(default_factory=LatencyConfig)
    dropout: DropoutConfig = field(default_factory=DropoutConfig)

    @property
    def past_s(self) -> float:
        """How far into the scene's past (s) the spaces of ``kinds`` read from its SUMO log (0: none)."""
        return max(SPACES.entry(k).past_s(self) for k in self.kinds)

    @property
    def needs_past(self) -> bool:
        """Does a space of ``kinds`` read the scene's past from its SUMO log (latency)?"""
        return self.past_s > 0

    @property
    def needs_lanes(self) -> bool:
        """Does a space of ``kinds``, or the plausibility level, read the scene's lanes?"""
        return self.plausibility == "traffic" or any(SPACES.entry(k).needs_lanes for k in self.kinds)

    @property
    def needs_movers(self) -> bool:
        """Does a space of ``kinds`` move the vehicles the occlusion heuristic picks (poses)?"""
        return any(SPACES.entry(k).needs_movers for k in self.kinds)

    def __post_init__(self) -> None:
        if not self.kinds:
            raise InputError(f"space.kinds is empty; name at least one of {', '.join(SPACES.names())}")
        for k in self.kinds:
            SPACES.check(k)
        if len(set(self.kinds)) != len(self.kinds):
            raise InputError(f"space.kinds names a space twice: {', '.join(self.kinds)}")
        checks.number(self.dxy_m, "space.dxy_m", 0.0, MAX_DXY_M, lo_open=True)
        checks.number(self.dyaw_deg, "space.dyaw_deg", 0.0, 180.0, lo_open=True)
        checks.number(self.dyaw_step_deg, "space.dyaw_step_deg", 0.0, self.dyaw_deg)
        checks.number(self.n_q, "space.n_q", 1, 1_000_000)
        checks.number(self.max_draw_factor, "space.max_draw_factor", 1, 10_000)
        if self.plausibility not in PLAUSIBILITY_LEVELS:
            raise InputError(f"space.plausibility must be one of {', '.join(PLAUSIBILITY_LEVELS)}, got {self.plausibility!r}")
        checks.number(self.traffic_heading_deg, "space.traffic_heading_deg", 0.0, 90.0, lo_open=True)

    def scale_per_vehicle(self) -> np.ndarray:
        """(3,) the bounds of one vehicle's move: dx_m, dy_m, dyaw_rad (x = 1 in normalised units)."""
        return np.array([self.dxy_m, self.dxy_m, math.radians(self.dyaw_deg)])

    def yaw_levels(self) -> np.ndarray | None:
        """(L,) the turns a moved vehicle may take, in normalised units (1 = dyaw_deg), ascending:
        the multiples of dyaw_step_deg within +-dyaw_deg; None when any turn is allowed."""
        if self.dyaw_step_deg <= 0.0:
            return None
        k = int(math.floor(self.dyaw_deg / self.dyaw_step_deg + 1e-9))
        return np.arange(-k, k + 1) * (self.dyaw_step_deg / self.dyaw_deg)


#: where an absent slot "stands" for the pair test (m): farther than any two vehicles can be apart
FAR_M = 1.0e9
#: a move larger than this (m) is no longer a nudge within the lane's neighbourhood
MAX_DXY_M = 20.0


def nearest_index(points: np.ndarray, x: np.ndarray) -> int:
    """Row of ``points`` (K, D) nearest to ``x`` (D,) in L2 (the first of ties)."""
    return int(np.argmin(np.sum((points - np.asarray(x)[None]) ** 2, axis=1)))


class EmptyFeasibleSet(InputError):
    """No sampled perturbation is plausible (e.g. vehicles boxed in): the scene cannot be perturbed."""


@dataclass(frozen=True)
class Perturbation:
    """What a member does: the placed vehicles by id (None: an inserted one left out) and, per
    collaborator whose message it changes, the link state."""

    moved: dict[str, Agent | None]
    link: dict[str, LinkState]


class SearchSpace:
    """The spaces of ``cfg.kinds`` over a scene (after ACS) and its m perturbed vehicles ``movers``."""

    def __init__(self, scene: Scene, movers: Sequence[str], cfg: SpaceConfig = SpaceConfig()):
        self.scene = scene
        self.vehicle_ids = tuple(movers)
        self.cfg = cfg
        ctx = SpaceContext(scene, self.vehicle_ids)
        self.parts = [SPACES.entry(k)(ctx, cfg) for k in cfg.kinds]
        self.slots: list[Slot] = [slot for p in self.parts for slot in p.slots]
        self.link_parts = [p for p in self.parts if p.width]
        self._slot_cuts = np.cumsum([0] + [s.width for s in self.slots])
        self._link_cuts = self._slot_cuts[-1] + np.cumsum([0] + [p.width for p in self.link_parts])

    @property
    def dim(self) -> int:
        return int(self._link_cuts[-1])

    @property
    def movable_ids(self) -> tuple[str, ...]:
        """The agents a render must be able to place: moved vehicles and insertion slots."""
        return tuple(s.agent_id for s in self.slots)

    @property
    def world_scene(self) -> Scene:
        """The scene with every insertion slot present (at its first candidate), for a World whose
        movable agents are :attr:`movable_ids`; a render passes each slot's state."""
        have = {a.agent_id for a in self.scene.agents}
        extra = [_placeholder(s) for s in self.slots if s.agent_id not in have]
        return self.scene.with_agents(list(self.scene.agents) + extra) if extra else self.scene

    def identity(self) -> np.ndarray:
        """(dim,) the member that changes nothing."""
        parts = [s.identity() for s in self.slots] + [p.identity() for p in self.link_parts]
        return np.concatenate(parts) if parts else np.zeros(0)

    def slot_values(self, x: np.ndarray) -> list[np.ndarray]:
        return [np.asarray(x)[a:b] for a, b in zip(self._slot_cuts[:-1], self._slot_cuts[1:])]

    def link_values(self, x: np.ndarray) -> list[np.ndarray]:
        return [np.asarray(x)[a:b] for a, b in zip(self._link_cuts[:-1], self._link_cuts[1:])]

    def decode(self, x: np.ndarray) -> Perturbation:
        moved = {s.agent_id: s.agent(v) for s, v in zip(self.slots, self.slot_values(x))}
        fields: dict[str, dict] = {}
        for part, v in zip(self.link_parts, self.link_values(x)):
            for cid, f in part.link_fields(v).items():
                fields.setdefault(cid, {}).update(f)
        return Perturbation(moved, {cid: LinkState(**f) for cid, f in fields.items()})

    def moved_agents(self, x: np.ndarray) -> dict[str, Agent | None]:
        return self.decode(x).moved

    def apply(self, x: np.ndarray) -> Scene:
        """The scene with member ``x`` applied: vehicles moved, inserted ones added, the link record set."""
        p = self.decode(x)
        agents = [p.moved.get(a.agent_id, a) for a in self.scene.agents]
        have = {a.agent_id for a in self.scene.agents}
        agents += [a for aid, a in p.moved.items() if aid not in have and a is not None]
        return self.scene.with_agents([a for a in agents if a is not None]).with_link(p.link)

    def columns(self) -> list[str]:
        """history.csv's column names for a member (with units)."""
        return [c for s in self.slots for c in s.columns()] + [c for p in self.link_parts for c in p.link_columns()]

    def readable(self, x: np.ndarray) -> list[float]:
        """Member ``x`` in the units of :meth:`columns`."""
        return [v for s, xs in zip(self.slots, self.slot_values(x)) for v in s.readable(xs)] + \
            [v for p, xs in zip(self.link_parts, self.link_values(x)) for v in p.link_readable(xs)]

    def bounds(self) -> dict:
        """Each space's bounds, as summary.json records them."""
        return {p.registry_name: p.bounds() for p in self.parts}


def _placeholder(slot) -> Agent:
    """An insertion slot's agent for the World's list of movable agents (renders always place it)."""
    from dataclasses import replace

    return replace(slot.template, agent_id=slot.agent_id)


@dataclass
class _Pool:
    """One slot's candidates that pass its own constraints: normalised (K, width), the placed
    vehicle's fcl box (None: absent) and centre (K, 2), the draws used, the slot's radius."""

    x: np.ndarray
    objects: list
    xy: np.ndarray
    drawn: int
    radius_m: float

    @cached_property
    def present(self) -> np.ndarray:
        """(K,) bool: candidates that place a vehicle (derived once: the pair test reads it per batch)."""
        return np.array([o is not None for o in self.objects], dtype=bool)


class FeasibleSet:
    """Q: plausible joint perturbations (K, dim) in normalised units; row 0 is always the identity.

    The physical slots are sampled in two steps, with the same distribution as drawing joint
    perturbations uniformly and rejecting the implausible ones, but far fewer draws: each slot's own
    constraints (on the drivable area, in range, clear of everything that does not move) do not
    depend on the other slots, so each slot first gets a pool of candidates that pass them; joint
    samples then combine one candidate from each pool at random and are kept only if the placed
    vehicles stay clear of each other. Joint rejection sampling needs about 1 / (p_1 ... p_m) draws
    per member; in a dense lane (p_i of a few percent each) it filled only a few dozen of the 1000
    members in 20,000 draws. Each member then gets link values drawn uniformly (independent of the
    physical ones).
    """

    def __init__(self, space: SearchSpace, rng: np.random.Generator):
        self.space = space
        cfg = space.cfg
        self.drawn = 0
        physical = self._physical_members(rng) if space.slots else np.zeros((cfg.n_q + 1, 0))
        n = len(physical)
        links = [p.sample(rng, n - 1) for p in space.link_parts]
        identity = space.identity()
        rows = np.concatenate([physical[1:]] + links, axis=1) if n > 1 else np.zeros((0, space.dim))
        members = np.concatenate([identity[None], rows]) if len(rows) else identity[None]
        _, first = np.unique(members, axis=0, return_index=True)  # discrete spaces repeat members: keep one each
        self.members = members[np.sort(first)]
        if len(self.members) < 2:
            raise EmptyFeasibleSet(f"scene {space.scene.scene_id}: the search space is empty")

    def _physical_members(self, rng: np.random.Generator) -> np.ndarray:
        space, cfg = self.space, self.space.cfg
        checker = FeasibilityChecker(space.scene, space.vehicle_ids, cfg.plausibility, cfg.traffic_heading_deg)
        budget = cfg.n_q * cfg.max_draw_factor
        pools = [self._slot_pool(checker, slot, rng, budget) for slot in space.slots]
        self.drawn = sum(p.drawn for p in pools)
        empty = [s.agent_id for s, p in zip(space.slots, pools) if not p.present.any()]
        if empty:
            raise EmptyFeasibleSet(
                f"scene {space.scene.scene_id}: no plausible move for vehicle {empty[0]} in {budget} draws "
                "(boxed in; for an inserted one, no free lane position); the scene cannot be perturbed")
        kept = [np.concatenate([s.identity() for s in space.slots])]
        drawn = 0
        while len(kept) < cfg.n_q + 1 and drawn < budget:
            batch = min(256, budget - drawn)
            picks = np.stack([rng.integers(0, len(p.x), size=batch) for p in pools], axis=1)  # (batch, slots)
            drawn += batch
            for row in picks[self._clear_pairs(pools, picks)]:
                kept.append(np.concatenate([p.x[k] for p, k in zip(pools, row)]))
                if len(kept) >= cfg.n_q + 1:
                    break
        self.drawn += drawn
        if len(kept) < 2:
            raise EmptyFeasibleSet(
                f"scene {space.scene.scene_id}: no plausible joint move for vehicles {', '.join(space.movable_ids)} "
                f"in {drawn} draws (each can move alone, not together); the scene cannot be perturbed")
        return np.array(kept)

    @staticmethod
    def _clear_pairs(pools: list["_Pool"], picks: np.ndarray) -> np.ndarray:
        """(batch,) bool: the picked candidates (batch, slots) keep every pair of placed vehicles
        apart. Pairs whose bounding circles are apart, or with one absent, are clear without asking fcl."""
        ok = np.ones(len(picks), dtype=bool)
        for i in range(len(pools)):
            for j in range(i + 1, len(pools)):
                gap = np.linalg.norm(pools[i].xy[picks[:, i]] - pools[j].xy[picks[:, j]], axis=1)
                both = pools[i].present[picks[:, i]] & pools[j].present[picks[:, j]]
                near = np.flatnonzero(ok & both & (gap < pools[i].radius_m + pools[j].radius_m))
                for r in near:
                    ok[r] = not collide_boxes(pools[i].objects[picks[r, i]], pools[j].objects[picks[r, j]])
        return ok

    def _slot_pool(self, checker: FeasibilityChecker, slot: Slot, rng: np.random.Generator, budget: int) -> "_Pool":
        """Up to N_Q candidates of one slot that pass its own constraints (an absent one always does)."""
        n_q = self.space.cfg.n_q
        xs: list[np.ndarray] = []
        objects: list = []
        xy: list[tuple[float, float]] = []
        drawn, body = 0, slot.body
        while len(xs) < n_q and drawn < budget:
            batch = min(512, budget - drawn)
            draws = slot.draw(rng, batch)
            drawn += batch
            poses = slot.poses(draws)
            real = np.flatnonzero(poses.present)
            ok = np.ones(batch, dtype=bool)
            if len(real):
                centres_xy = poses.centres_xy[real]
                ok[real] = (checker.on_road(centres_xy, poses.yaws_rad[real], body.length_m, body.width_m)
                            & checker.in_range(centres_xy))
            for i in np.flatnonzero(ok):
                box, centre = None, (FAR_M, FAR_M)
                if poses.present[i]:
                    centre = tuple(poses.centres_xy[i])
                    box = box_object_at(body, *centre, poses.yaws_rad[i])
                    if checker.touches_fixed(box):
                        continue
                xs.append(draws[i])
                objects.append(box)
                xy.append(centre)
                if len(xs) >= n_q:
                    break
        return _Pool(np.array(xs).reshape(-1, slot.width), objects, np.array(xy).reshape(-1, 2), drawn, slot.radius_m)

    def __len__(self) -> int:
        return len(self.members)

    def project(self, x: np.ndarray) -> np.ndarray:
        """The member of Q nearest to ``x`` in normalised units."""
        return self.members[nearest_index(self.members, x)]

    def sample(self, rng: np.random.Generator) -> np.ndarray:
        return self.members[int(rng.integers(1, len(self.members)))]
