"""The parts a search space is made of; each perturbation space (poses, insert, pose-error, latency,
dropout) is one registered class built from the scene after ACS and the space's settings.

A member x of the search space is one vector in normalised units, [-1, 1] per dimension: first the
*slots* of every physical part (one per vehicle a member places: a moved vehicle's dx, dy, dyaw, an
inserted vehicle's presence, position and heading), then the *link* dimensions of every link part
(per collaborator). Physical slots must be plausible together (the feasible set checks them
jointly); link dimensions are free within their bounds.
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ...scene import Agent, Scene
from ...registry import Registry


@dataclass(frozen=True)
class SlotPoses:
    """Where n members of one slot place its vehicle (network frame): present (n,) bool, centres
    (n, 2) and headings (n,) (NaN where absent)."""

    present: np.ndarray
    centres_xy: np.ndarray
    yaws_rad: np.ndarray


class Slot(ABC):
    """One vehicle a member may place: ``width`` normalised numbers decode to its agent (None: absent)."""

    agent_id: str
    width: int
    #: radius (m) of the circle around its footprint (pairs of slots farther apart cannot collide)
    radius_m: float
    #: the vehicle whose size and ground height the slot places (a moved one as the scene has it,
    #: an inserted one's template)
    body: Agent

    @abstractmethod
    def draw(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """(n, width) candidates, uniform over this slot's own range (before plausibility)."""

    @abstractmethod
    def agent(self, x: np.ndarray) -> Agent | None:
        """The vehicle ``x`` (width,) places, in the network frame; None if absent."""

    def poses(self, draws: np.ndarray) -> SlotPoses:
        """Where each of ``draws`` (n, width) places the vehicle: the poses :meth:`agent` gives
        (an override computes them at once, to the same floats)."""
        agents = [self.agent(x) for x in draws]
        present = np.array([a is not None for a in agents], dtype=bool)
        centres_xy = np.array([(a.x_m, a.y_m) if a is not None else (np.nan, np.nan) for a in agents]).reshape(-1, 2)
        yaws_rad = np.array([a.yaw_rad if a is not None else np.nan for a in agents], dtype=float)
        return SlotPoses(present, centres_xy, yaws_rad)

    @abstractmethod
    def identity(self) -> np.ndarray:
        """(width,) the slot as in the scene (unmoved, or not inserted)."""

    @abstractmethod
    def readable(self, x: np.ndarray) -> list[float]:
        """The values written to history.csv for ``x`` (see ``columns``)."""

    @abstractmethod
    def columns(self) -> list[str]:
        """Column names (with units) of :meth:`readable`."""


@dataclass(frozen=True)
class SpaceContext:
    """What a space is built from: the scene after ACS (its collaborators set) and the vehicles the
    occlusion heuristic picked to move (m of them)."""

    scene: Scene
    movers: tuple[str, ...]


class PerturbationSpace(ABC):
    """A registered perturbation space: physical slots and/or link dimensions."""

    registry_name: str = ""
    #: the space moves the vehicles the occlusion heuristic picks (``SpaceContext.movers``): the
    #: generator picks them only when a space of the run asks
    needs_movers: bool = False
    #: the space reads the scene's lanes (free lane positions): a scene without lanes (a recording
    #: imported without a map) cannot take it
    needs_lanes: bool = False

    @classmethod
    def past_s(cls, cfg) -> float:
        """How far into the scene's past (s) the space reads, from its SUMO log, under the space
        settings ``cfg`` (a SpaceConfig); 0: it reads none (the source need not keep a log)."""
        return 0.0

    def __init__(self, ctx: SpaceContext, cfg) -> None:
        self.ctx = ctx
        self.cfg = cfg

    @property
    def slots(self) -> Sequence[Slot]:
        """The vehicles this space places (none for a link space)."""
        return ()

    # ---- link dimensions (none for a physical space) -----------------------------------------
    @property
    def width(self) -> int:
        """Link dimensions of this space."""
        return 0

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """(n, width) link members, uniform over the space's bounds."""
        return np.zeros((n, 0))

    def identity(self) -> np.ndarray:
        """(width,) a perfect link."""
        return np.zeros(0)

    def link_fields(self, x: np.ndarray) -> dict[str, dict]:
        """Per collaborator, the LinkState fields ``x`` (width,) sets."""
        return {}

    def link_columns(self) -> list[str]:
        return []

    def link_readable(self, x: np.ndarray) -> list[float]:
        return []

    @abstractmethod
    def bounds(self) -> dict:
        """The space's bounds as summary.json records them (units in the keys)."""


#: the perturbation spaces (``--space``), one module of this package each, filled by its import
SPACES: "Registry[type[PerturbationSpace]]" = Registry("perturbation space", "--space")


def collaborators(ctx: SpaceContext) -> tuple[str, ...]:
    """The collaborators whose messages a link space perturbs (never the ego)."""
    return ctx.scene.collaborators
