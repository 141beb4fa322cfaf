"""What the V2X link did to one collaborator's message: a scene's ``link`` record.

A collaborator's sensor always sees the true world; the link changes what reaches the ego:

- ``dx_m, dy_m, dyaw_rad``: the pose it shares is off by this much (localisation error), x and y in
  the network frame, yaw about the vertical;
- ``delay_s`` (> 0): its cloud was captured this long ago (message delay): rendered from the world of
  that earlier instant (``earlier_agents``: every agent near it then, itself included) at its pose of
  that instant, which is also the pose it shares;
- ``dropped``: the message never arrived (the ego fuses without it).

In a scene's yaml (optional; absent = a perfect link)::

    link:
      COLLABORATOR_ID: {dx_m, dy_m, dyaw_rad, delay_s, dropped, earlier_agents: [Agent, ...]}

Everything a re-render needs is in the record, so a scene with a link renders the same from its
yaml alone (no traffic log needed).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from sumo_scenarios import checks
from sumo_scenarios.errors import InputError

from .agent import Agent

#: a shared pose off by more than this (m) is not a localisation error but a different place
MAX_POSE_ERROR_M = 50.0
#: a message older than this (s) is not delayed but stale
MAX_DELAY_S = 10.0


@dataclass(frozen=True)
class LinkState:
    dx_m: float = 0.0
    dy_m: float = 0.0
    dyaw_rad: float = 0.0
    delay_s: float = 0.0
    dropped: bool = False
    #: delay_s > 0: the agents near the collaborator delay_s earlier (network frame), itself included
    earlier_agents: tuple[Agent, ...] = ()

    @property
    def is_perfect(self) -> bool:
        """Does the message arrive on time with the true pose?"""
        return not (self.dx_m or self.dy_m or self.dyaw_rad or self.delay_s or self.dropped)

    def earlier_self(self, agent_id: str) -> Agent:
        """The collaborator ``delay_s`` earlier (from ``earlier_agents``)."""
        for a in self.earlier_agents:
            if a.agent_id == agent_id:
                return a
        raise KeyError(agent_id)

    def to_dict(self) -> dict:
        out: dict = {"dx_m": float(self.dx_m), "dy_m": float(self.dy_m), "dyaw_rad": float(self.dyaw_rad),
                     "delay_s": float(self.delay_s), "dropped": bool(self.dropped)}
        if self.earlier_agents:
            out["earlier_agents"] = [a.to_dict() for a in self.earlier_agents]
        return out

    @staticmethod
    def from_dict(d, agent_id: str) -> "LinkState":
        """A record from yaml; every number checked, ``earlier_agents`` must hold ``agent_id`` when
        the message is delayed (an error names the link; the scene's loader names the file)."""
        where = f"link of '{agent_id}'"
        if not isinstance(d, dict):
            raise InputError(f"{where}: expected a mapping (dx_m, dy_m, dyaw_rad, delay_s, dropped)")
        unknown = sorted(set(d) - {"dx_m", "dy_m", "dyaw_rad", "delay_s", "dropped", "earlier_agents"})
        if unknown:
            raise InputError(f"{where}: unknown key '{unknown[0]}'")
        dropped = d.get("dropped", False)
        if not isinstance(dropped, bool):
            raise InputError(f"{where}: dropped must be true or false, got {dropped!r}")
        agents = d.get("earlier_agents") or []
        if not isinstance(agents, list):
            raise InputError(f"{where}: earlier_agents must be a list of agents")
        state = LinkState(
            dx_m=checks.number(d.get("dx_m", 0.0), f"{where} dx_m", -MAX_POSE_ERROR_M, MAX_POSE_ERROR_M),
            dy_m=checks.number(d.get("dy_m", 0.0), f"{where} dy_m", -MAX_POSE_ERROR_M, MAX_POSE_ERROR_M),
            dyaw_rad=checks.number(d.get("dyaw_rad", 0.0), f"{where} dyaw_rad", -math.pi, math.pi),
            delay_s=checks.number(d.get("delay_s", 0.0), f"{where} delay_s", 0.0, MAX_DELAY_S),
            dropped=dropped, earlier_agents=tuple(Agent.from_dict(a) for a in agents))
        if state.delay_s > 0:
            try:
                state.earlier_self(agent_id)
            except KeyError:
                raise InputError(f"{where}: delayed by {state.delay_s:g} s but earlier_agents lacks the "
                                 "collaborator itself") from None
        return state
