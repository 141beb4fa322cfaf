"""``latency``: a collaborator's cloud comes from up to ``max_delay_s`` earlier (whole time steps of
the scene's SUMO log, see asg.scene.history), rendered from the world of that instant and fused as
if current: the message delay of a real link. One discrete dimension per collaborator: delay k of
0..D steps as -1 + 2k/D.

Default 0.4 s: V2X-ViT evaluates delays up to 400 ms; 3GPP TS 22.186 budgets 100 ms end to end for
cooperative awareness, so the bound covers a link a few times slower than specified.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sumo_scenarios import checks
from sumo_scenarios.errors import InputError

from ...scene.history import HISTORY_MARGIN_S, History, earlier_agents, scene_history
from ...scene.link import MAX_DELAY_S
from .base import SPACES, PerturbationSpace, SpaceContext, collaborators


@dataclass(frozen=True)
class LatencyConfig:
    max_delay_s: float = 0.4

    def __post_init__(self) -> None:
        checks.number(self.max_delay_s, "space.latency.max_delay_s (seconds)", 0.0, min(MAX_DELAY_S, HISTORY_MARGIN_S),
                      lo_open=True)


@SPACES.register("latency")
class LatencySpace(PerturbationSpace):
    @classmethod
    def past_s(cls, cfg) -> float:
        return cfg.latency.max_delay_s

    def __init__(self, ctx: SpaceContext, cfg) -> None:
        super().__init__(ctx, cfg)
        self.history: History = scene_history(ctx.scene, 1_000, cfg.latency.max_delay_s)
        self.steps = self._steps_on_road()

    @property
    def width(self) -> int:
        return len(collaborators(self.ctx))

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        return -1.0 + 2.0 * rng.integers(0, self.steps + 1, size=(n, self.width)) / self.steps

    def identity(self) -> np.ndarray:
        return -np.ones(self.width)

    def delay_steps(self, x: np.ndarray) -> list[int]:
        return [int(round((v + 1.0) / 2.0 * self.steps)) for v in np.asarray(x)]

    def link_fields(self, x: np.ndarray) -> dict[str, dict]:
        out = {}
        for cid, k in zip(collaborators(self.ctx), self.delay_steps(x)):
            out[cid] = {"delay_s": round(k * self.history.period_s, 6), "earlier_agents": self.earlier_agents(cid, k)}
        return out

    def _steps_on_road(self) -> int:
        """D: the delays (in log periods) at which every collaborator was already on the road."""
        steps = 0
        for frame in self.history.frames:
            ids = {a.agent_id for a in frame}
            if not all(c in ids for c in collaborators(self.ctx)):
                break
            steps += 1
        if steps == 0:
            raise InputError(f"scene {self.ctx.scene.scene_id}: a collaborator was not on the road "
                             f"{self.history.period_s:g} s earlier; no delay can be rendered")
        return steps

    def earlier_agents(self, agent_id: str, steps: int) -> tuple:
        """The agents around ``agent_id`` ``steps`` periods earlier (asg.scene.history.earlier_agents)."""
        return earlier_agents(self.ctx.scene, self.history, agent_id, steps)

    def link_columns(self) -> list[str]:
        return [f"{c}_delay_s" for c in collaborators(self.ctx)]

    def link_readable(self, x: np.ndarray) -> list[float]:
        return [round(k * self.history.period_s, 6) for k in self.delay_steps(x)]

    def bounds(self) -> dict:
        return {"max_delay_s": self.cfg.latency.max_delay_s, "step_s": self.history.period_s, "steps": self.steps}
