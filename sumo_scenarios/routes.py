"""Seeded random routes from SUMO's own randomTrips.py (validated with duarouter)."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from . import sumo_tools
from .vehicles import MIX_ID

Density = Literal["normal", "dense"]


@dataclass(frozen=True)
class TrafficParams:
    """Demand: vehicles inserted per hour per km of road (randomTrips' ``--insertion-density``)."""

    normal_per_km_hour: float = 600.0
    dense_per_km_hour: float = 1300.0
    fringe_factor: float = 10.0
    min_distance_m: float = 150.0

    #: town-specific multiplier (``demand_scale`` in configs/towns.yaml)
    scale: float = 1.0

    def density_value(self, density: Density) -> float:
        base = self.dense_per_km_hour if density == "dense" else self.normal_per_km_hour
        return base * self.scale


def make_routes(net_path: Path, vtypes_path: Path, out_path: Path, seed: int, end_s: float,
                density: Density, params: TrafficParams = TrafficParams()) -> Path:
    """Write a route file for ``[0, end_s]`` seconds of traffic; returns ``out_path``."""
    trips = out_path.with_name(out_path.name.replace(".rou.xml", ".trips.xml"))
    sumo_tools.run_python_tool(
        "randomTrips.py",
        [
            "-n", str(net_path), "-o", str(trips), "-r", str(out_path),
            "--seed", str(seed), "-b", "0", "-e", f"{end_s:.1f}",
            "--insertion-density", str(params.density_value(density)),
            "--fringe-factor", str(params.fringe_factor),
            "--min-distance", str(params.min_distance_m),
            "--trip-attributes", f'type="{MIX_ID}" departLane="best" departSpeed="max"',
            "--additional-file", str(vtypes_path),
            "--remove-loops", "--validate",
        ],
        f"randomTrips for {net_path.name}",
    )
    return out_path
