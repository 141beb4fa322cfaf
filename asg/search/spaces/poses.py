"""``poses``: the paper's space. Each of the m vehicles the occlusion heuristic picked moves by
(dx, dy) within +-dxy_m (network frame) and turns by dyaw within +-dyaw_deg (space settings)."""
from __future__ import annotations

import math

import numpy as np

from ...registry import register
from ...scene import Agent
from .base import PerturbationSpace, Slot


class MoveSlot(Slot):
    width = 3

    def __init__(self, base: Agent, scale: np.ndarray):
        self.base = base
        self.agent_id = base.agent_id
        self.scale = scale  # (3,) dx_m, dy_m, dyaw_rad at x = 1
        self.radius_m = 0.5 * math.hypot(base.length_m, base.width_m)

    def draw(self, rng: np.random.Generator, n: int) -> np.ndarray:
        return rng.uniform(-1.0, 1.0, size=(n, 3))

    def agent(self, x: np.ndarray) -> Agent:
        return self.base.moved(*(np.asarray(x) * self.scale))

    def identity(self) -> np.ndarray:
        return np.zeros(3)

    def readable(self, x: np.ndarray) -> list[float]:
        dx, dy, dyaw = np.asarray(x) * self.scale
        return [round(float(dx), 4), round(float(dy), 4), round(math.degrees(dyaw), 4)]

    def columns(self) -> list[str]:
        return [f"{self.agent_id}_{k}" for k in ("dx_m", "dy_m", "dyaw_deg")]


@register("space", "poses")
class PosesSpace(PerturbationSpace):
    @property
    def slots(self) -> list[MoveSlot]:
        scale = self.cfg.scale_per_vehicle()
        return [MoveSlot(self.ctx.scene.agent(vid), scale) for vid in self.ctx.movers]

    def bounds(self) -> dict:
        return {"movers": len(self.ctx.movers), "dxy_m": self.cfg.dxy_m, "dyaw_deg": self.cfg.dyaw_deg}
