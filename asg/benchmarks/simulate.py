"""``asg bench simulate``: wall time of 10 simulated minutes of dense traffic at 0.1 s steps."""
from __future__ import annotations

import statistics
import tempfile
import time
from pathlib import Path

from sumo_scenarios.simulate import SimulationRequest, simulate_sumo

from .defaults import SIMULATE_MINUTES, SIMULATE_REPEATS, SIMULATE_TOWN


def bench_simulate(town: str = SIMULATE_TOWN, minutes: float = SIMULATE_MINUTES, repeats: int = SIMULATE_REPEATS,
                   seed: int = 1) -> dict:
    """Run ``repeats`` simulations (warm-up included in the simulated time) and report medians.

    ``wall_s_median`` covers everything ``asg simulate`` does: routes, libsumo run, fcd writing,
    statistics; ``libsumo_wall_s_median`` only the libsumo stepping.
    """
    walls, sim_walls, stats = [], [], {}
    duration_s = minutes * 60.0
    warmup_s = 60.0
    for r in range(repeats):
        with tempfile.TemporaryDirectory() as tmp:
            t0 = time.perf_counter()
            stats = simulate_sumo(SimulationRequest(out_dir=Path(tmp) / "log", town=town, seed=seed + r,
                                                    duration_s=duration_s - warmup_s, warmup_s=warmup_s,
                                                    density="dense", step_s=0.1))
            walls.append(time.perf_counter() - t0)
            sim_walls.append(stats["wall_s"])
    steps = duration_s / 0.1
    return {
        "town": town, "density": "dense", "simulated_s": duration_s, "step_s": 0.1, "repeats": repeats,
        "wall_s_median": round(statistics.median(walls), 2),
        "libsumo_wall_s_median": round(statistics.median(sim_walls), 2),
        "steps_per_s": round(steps / statistics.median(sim_walls), 1),
        "vehicles_median": stats.get("vehicles_median"),
        "near_rsu_median": stats.get("near_rsu_median"),
        "goal_wall_s": 10.0,
    }
