"""Seeded random routes from SUMO's own randomTrips.py (validated with duarouter)."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal, get_args

from . import sumo_tools
from .vehicles import MIX_ID

Density = Literal["normal", "dense"]
#: the traffic densities every town knows (``asg simulate --density``, data sets' ``densities``)
DENSITIES: tuple[str, ...] = get_args(Density)


@dataclass(frozen=True)
class TrafficParams:
    """Demand and the level it settles at.

    Trips are inserted at ``insert_per_km_hour`` vehicles per hour per km of road (randomTrips'
    ``--insertion-density``; half that for ``normal``), more than the town can absorb, and SUMO
    holds the number of vehicles in the network at ``*_per_lane_km`` x lane length
    (``--max-num-vehicles``): traffic fills the town during the warm-up, then stays at that level
    instead of drifting into gridlock. ``scale`` is the town's ``demand_scale`` (configs/towns.yaml).
    """

    normal_per_lane_km: float = 14.0
    dense_per_lane_km: float = 30.0
    insert_per_km_hour: float = 2400.0
    fringe_factor: float = 10.0
    min_distance_m: float = 150.0
    scale: float = 1.0

    def max_vehicles(self, density: Density, lane_km: float) -> int:
        per_km = self.dense_per_lane_km if density == "dense" else self.normal_per_lane_km
        return max(1, int(round(per_km * self.scale * lane_km)))

    def insertion_density(self, density: Density) -> float:
        return self.insert_per_km_hour * self.scale * (1.0 if density == "dense" else 0.5)


def make_routes(net_path: Path, vtypes_path: Path, out_path: Path, seed: int, end_s: float,
                density: Density, params: TrafficParams = TrafficParams(), label: str | None = None) -> Path:
    """Write a route file for ``[0, end_s]`` seconds of traffic; returns ``out_path``. ``label``
    names the net in errors (the user's town or file, not the copy being worked on)."""
    trips = out_path.with_name(out_path.name.replace(".rou.xml", ".trips.xml"))
    sumo_tools.run_python_tool(
        "randomTrips.py",
        [
            "-n", str(net_path), "-o", str(trips), "-r", str(out_path),
            "--seed", str(seed), "-b", "0", "-e", f"{end_s:.1f}",
            "--insertion-density", str(params.insertion_density(density)),
            "--fringe-factor", str(params.fringe_factor),
            "--min-distance", str(params.min_distance_m),
            "--trip-attributes", f'type="{MIX_ID}" departLane="best" departSpeed="max"',
            "--additional-file", str(vtypes_path),
            "--remove-loops", "--validate",
        ],
        f"making routes for {label or net_path.name} (SUMO's randomTrips)",
    )
    return out_path
