"""``poses``: the paper's space. Each of the m vehicles the occlusion heuristic picked moves by
(dx, dy) within +-dxy_m (network frame) and turns by dyaw within +-dyaw_deg, in steps of
dyaw_step_deg if that is set (space settings)."""
from __future__ import annotations

import math

import numpy as np

from sumo_scenarios.geometry import wrap_rad

from ...scene import Agent
from .base import SPACES, PerturbationSpace, Slot, SlotPoses


class MoveSlot(Slot):
    width = 3

    def __init__(self, base: Agent, scale: np.ndarray, yaw_levels: np.ndarray | None = None):
        self.base = self.body = base
        self.agent_id = base.agent_id
        self.scale = scale  # (3,) dx_m, dy_m, dyaw_rad at x = 1
        self.yaw_levels = yaw_levels  # (L,) the allowed turns in normalised units, or None: any
        self.radius_m = 0.5 * math.hypot(base.length_m, base.width_m)

    def draw(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """(n, 3) normalised dx, dy, dyaw: uniform in [-1, 1], the turn uniform over ``yaw_levels`` if set."""
        x = rng.uniform(-1.0, 1.0, size=(n, 3))
        if self.yaw_levels is not None:
            x[:, 2] = self.yaw_levels[rng.integers(len(self.yaw_levels), size=n)]
        return x

    def agent(self, x: np.ndarray) -> Agent:
        return self.base.moved(*(np.asarray(x) * self.scale))

    def poses(self, draws: np.ndarray) -> SlotPoses:
        """:meth:`agent`'s poses of ``draws`` (n, 3) at once: the same products, sums and wrap."""
        d = np.asarray(draws, dtype=float).reshape(-1, 3) * self.scale
        centres_xy = np.stack([self.base.x_m + d[:, 0], self.base.y_m + d[:, 1]], axis=1)
        return SlotPoses(np.ones(len(d), dtype=bool), centres_xy, wrap_rad(self.base.yaw_rad + d[:, 2]))

    def identity(self) -> np.ndarray:
        return np.zeros(3)

    def readable(self, x: np.ndarray) -> list[float]:
        dx, dy, dyaw = np.asarray(x) * self.scale
        return [round(float(dx), 4), round(float(dy), 4), round(math.degrees(dyaw), 4)]

    def columns(self) -> list[str]:
        return [f"{self.agent_id}_{k}" for k in ("dx_m", "dy_m", "dyaw_deg")]


@SPACES.register("poses")
class PosesSpace(PerturbationSpace):
    needs_movers = True
    @property
    def slots(self) -> list[MoveSlot]:
        scale, levels = self.cfg.scale_per_vehicle(), self.cfg.yaw_levels()
        return [MoveSlot(self.ctx.scene.agent(vid), scale, levels) for vid in self.ctx.movers]

    def bounds(self) -> dict:
        return {"movers": len(self.ctx.movers), "dxy_m": self.cfg.dxy_m, "dyaw_deg": self.cfg.dyaw_deg,
                "dyaw_step_deg": self.cfg.dyaw_step_deg}
