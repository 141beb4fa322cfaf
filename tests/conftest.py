"""Shared fixtures: tiny hand-built maps, and simulated logs made once per test session."""
from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np
import pytest

# the user's asg folder (imported towns) of this test session: never the real one
os.environ["ASG_HOME"] = tempfile.mkdtemp(prefix="asg-home-")

from sumo_scenarios.lanes import Junction, Lane, LaneMap


@pytest.fixture
def cross_map() -> LaneMap:
    """Two 2-lane roads crossing at a 14 m square junction centred on the origin.

    East-west road: lanes 'we_0' (y = -1.6, eastbound) and 'ew_0' (y = +1.6, westbound), each 3.2 m
    wide, x from -100 to -7 and 7 to 100. North-south road likewise along x.
    """
    w = 3.2
    lanes = [
        Lane("we_0", np.array([[-100.0, -1.6], [-7.0, -1.6]]), w, 13.9),
        Lane("we2_0", np.array([[7.0, -1.6], [100.0, -1.6]]), w, 13.9),
        Lane("ew_0", np.array([[100.0, 1.6], [7.0, 1.6]]), w, 13.9),
        Lane("ew2_0", np.array([[-7.0, 1.6], [-100.0, 1.6]]), w, 13.9),
        Lane("sn_0", np.array([[1.6, -100.0], [1.6, -7.0]]), w, 13.9),
        Lane("ns_0", np.array([[-1.6, 100.0], [-1.6, 7.0]]), w, 13.9),
    ]
    square = np.array([[-7.0, -7.0], [7.0, -7.0], [7.0, 7.0], [-7.0, 7.0]])
    return LaneMap(lanes, [Junction("J", square, "traffic_light", (0.0, 0.0))])


@pytest.fixture(scope="session")
def sumo_log(tmp_path_factory) -> Path:
    """60 recorded seconds of normal traffic in grid_small (seed 3)."""
    from sumo_scenarios.simulate import SimulationRequest, simulate_sumo

    out = tmp_path_factory.mktemp("logs") / "grid_normal"
    simulate_sumo(SimulationRequest(out_dir=out, town="grid_small", seed=3, duration_s=60.0, density="normal", warmup_s=60.0))
    return out


@pytest.fixture(scope="session")
def highway_log(tmp_path_factory) -> Path:
    """60 recorded seconds of highway-env's intersection-v0 (seed 2)."""
    from sumo_scenarios.highway import HighwayRequest, simulate_highway

    out = tmp_path_factory.mktemp("logs") / "hw_intersection"
    simulate_highway(HighwayRequest(out_dir=out, env_id="intersection-v0", seed=2, duration_s=60.0))
    return out


def car(agent_id: str, x: float, y: float, yaw: float = 0.0, type_id: str = "car"):
    """A vehicle agent with the bundled size of its type."""
    from asg.scene import Agent
    from sumo_scenarios.vehicles import VEHICLE_TYPES

    t = {v.type_id: v for v in VEHICLE_TYPES}[type_id]
    return Agent(agent_id, "vehicle", type_id, x, y, 0.0, yaw, t.length_m, t.width_m, t.height_m, 0.0, None)


def rsu(agent_id: str, x: float, y: float):
    from asg.scene import Agent

    return Agent(agent_id, "rsu", "rsu", x, y, 0.0, 0.0, 0.4, 0.4, 4.5)


def make_scene(lane_map, agents, buildings=(), ego: str | None = None, collaborators=()):
    from asg.scene import Scene

    return Scene("test", "synthetic", "sumo", 0.0, ego or agents[0].agent_id, tuple(agents), tuple(buildings),
                 lane_map, tuple(collaborators))
